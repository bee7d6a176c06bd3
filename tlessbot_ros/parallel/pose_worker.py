"""A pose worker process: ``python -m tlessbot_ros.parallel.pose_worker``.

Reads messages (:mod:`~tlessbot_ros.parallel.wire`) on stdin, answers on stdout:

1. ``{"templates": path, "pose": {PoseParams}, "fit": {FitParams}}`` -> loads the
   template database, builds every cache, answers ``{"ready": n_objects}`` (or ``{"error":
   text}`` and exits 1);
2. then per part ``{"job": id, "candidates": [...], "T_world_camera": [16] | null}`` with the
   ROI points as payload -> ``{"job": id, "obj_id", "class_rank", "pose", "second"}`` (or
   ``{"job": id, "error": text}``), until stdin closes.

Anything a library prints goes to stderr: stdout carries the protocol only.
"""
from __future__ import annotations

import os
import signal
import sys
from typing import Any, BinaryIO

from tlessbot_ros.core.pipeline import Detection, FitParams, PartJob, PerceptionPipeline
from tlessbot_ros.core.pose import PoseParams, TemplateDatabase
from tlessbot_ros.io.cache import warm_pose_stage
from tlessbot_ros.parallel.wire import (
    WireError,
    candidate_to_json,
    matrix_from_json,
    params_from_json,
    points_from_bytes,
    read_message,
    write_message,
)


def pipeline_from_config(config: dict[str, Any]) -> PerceptionPipeline:
    """The pipeline a worker fits with, from its start-up message."""
    return PerceptionPipeline(templates=TemplateDatabase.load(config['templates']),
                              pose=params_from_json(PoseParams, config.get('pose', {})),
                              fit_params=params_from_json(FitParams, config.get('fit', {})))


def fit(pipeline: PerceptionPipeline, header: dict[str, Any], payload: bytes) -> dict[str, Any]:
    """Answer one job message."""
    candidates = tuple(int(c) for c in header['candidates'])
    job = PartJob(Detection(0, candidates[0], '', (0, 0, 0, 0)), points_from_bytes(payload),
                  candidates, matrix_from_json(header.get('T_world_camera')))
    pipeline.fit_part(job)
    detection = job.detection
    return {'job': header['job'], 'obj_id': detection.obj_id,
            'class_rank': detection.class_rank, 'pose': candidate_to_json(detection.pose),
            'second': candidate_to_json(detection.second)}


def serve(requests: BinaryIO, replies: BinaryIO) -> int:
    """The worker's loop; returns the exit code."""
    try:
        config, _ = read_message(requests)
        pipeline = pipeline_from_config(config)
        warm_pose_stage(pipeline, config['templates'])   # the node's start-up cache, if any
    except WireError:
        return 0
    except Exception as error:  # report why, so the node can log it
        write_message(replies, {'error': f'{type(error).__name__}: {error}'})
        return 1
    write_message(replies, {'ready': len(pipeline.pose_estimator.database.objects)})
    while True:
        try:
            header, payload = read_message(requests)
        except WireError:
            return 0  # the node closed the pipe: done
        try:
            reply = fit(pipeline, header, payload)
        except Exception as error:  # a bad part must not end the worker
            reply = {'job': header.get('job'), 'error': f'{type(error).__name__}: {error}'}
        write_message(replies, reply)


def main() -> None:
    # Ctrl-C reaches the whole process group; the node ends this worker by closing its input.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The protocol keeps the real stdout; fd 1 becomes stderr, so that C++ libraries (Open3D
    # warnings) cannot write into the protocol stream.
    replies = os.fdopen(os.dup(sys.stdout.fileno()), 'wb')
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    code = serve(sys.stdin.buffer, replies)
    # The node waits for this exit when it stops (Ctrl-C). Finalising the interpreter (the
    # template arrays, Open3D, numba) took 1.4 s on the 2-core machine under load, more than
    # the node's wait; nothing here needs it (the replies are flushed, no file is written).
    for stream in (replies, sys.stderr):
        try:
            stream.flush()
        except OSError:   # the node is gone
            pass
    os._exit(code)


if __name__ == '__main__':
    main()
