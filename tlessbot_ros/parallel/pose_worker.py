"""A pose worker process: ``python -m tlessbot_ros.parallel.pose_worker [NODE_PID]``.

Reads messages (:mod:`~tlessbot_ros.parallel.wire`) on stdin, answers on stdout:

1. ``{"templates": path, "pose": {PoseParams}, "fit": {FitParams}}`` -> loads the
   template database, builds every cache, answers ``{"ready": n_objects}`` (or ``{"error":
   text}`` and exits 1);
2. then per part ``{"job": id, "candidates": [...], "T_world_camera": [16] | null}`` (in box
   mode with ``"box": [x, y, w, h], "box_camera": [9]``) with the ROI points as payload, and
   ``"params": {"pose": {...}, "fit": {...}}`` when the node's settings changed since the
   worker's last part (kept for the parts after it) ->
   ``{"job": id, "obj_id", "class_rank", "pose", "second"}`` (or ``{"job": id, "error":
   text}``), until stdin closes.

Anything a library prints goes to stderr: stdout carries the protocol only.

A worker never outlives its node: idle, it reads the end of its input when the node dies; busy
(loading templates, fitting a part), a watch thread sees that NODE_PID is no longer its parent
and ends the process at once. A node killed with SIGKILL (or by the OOM killer) therefore
leaves no ~430 MiB orphan fitting parts for nobody while its successor starts.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time
from dataclasses import replace
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
                              fit_params=_fit_params(config.get('fit', {})))


def _fit_params(values: dict[str, Any]) -> FitParams:
    """The node's FitParams without the look-alike check: the node runs it on the fitted
    poses (it reads every view, which a worker does not have), so a worker would only build
    and warm up its meshes for nothing."""
    return replace(params_from_json(FitParams, values), lookalike_check=False)


def with_settings(pipeline: PerceptionPipeline, settings: dict[str, Any]) -> PerceptionPipeline:
    """The pipeline with a job's new ``{"pose": {PoseParams}, "fit": {FitParams}}`` (the
    node's parameters changed); templates and their caches are kept."""
    return pipeline.replace(pose=params_from_json(PoseParams, settings.get('pose', {})),
                            fit_params=_fit_params(settings.get('fit', {})))


def fit(pipeline: PerceptionPipeline, header: dict[str, Any], payload: bytes) -> dict[str, Any]:
    """Answer one job message."""
    candidates = tuple(int(c) for c in header['candidates'])
    box = tuple(int(v) for v in header.get('box', (0, 0, 0, 0)))
    box_camera = header.get('box_camera')
    job = PartJob(Detection(0, candidates[0], '', (box[0], box[1], box[2], box[3])),
                  points_from_bytes(payload), candidates,
                  matrix_from_json(header.get('T_world_camera')),
                  box_camera=matrix_from_json(box_camera, 3))
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
            if 'params' in header:
                pipeline = with_settings(pipeline, header['params'])
            reply = fit(pipeline, header, payload)
        except Exception as error:  # a bad part must not end the worker
            reply = {'job': header.get('job'), 'error': f'{type(error).__name__}: {error}'}
        write_message(replies, reply)


def exit_with_parent(parent_pid: int, interval_s: float = 0.2) -> threading.Thread:
    """Watch, on a daemon thread, that ``parent_pid`` is still this process's parent, and end
    the process (exit code 0) when it is not: the node died and this worker was handed to
    init or a subreaper.

    PR_SET_PDEATHSIG would be quicker but is tied to the parent's *thread* that started the
    worker, not its process: the pool starts replacement workers from the stage's frame thread,
    and a worker would be killed with any short-lived thread that happened to start it.
    """
    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(interval_s)
        os._exit(0)   # nobody reads the answers any more; flush nothing into a dead pipe

    thread = threading.Thread(target=watch, name='parent_watch', daemon=True)
    thread.start()
    return thread


def main() -> None:
    # The node gives its pid: a worker whose node died before this line runs must end too.
    exit_with_parent(int(sys.argv[1]) if len(sys.argv) > 1 else os.getppid())
    # Ctrl-C reaches the whole process group; the node ends this worker by closing its input.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # The protocol keeps the real stdout; fd 1 becomes stderr, so that C++ libraries (Open3D
    # warnings) cannot write into the protocol stream.
    replies = os.fdopen(os.dup(sys.stdout.fileno()), 'wb')
    os.dup2(sys.stderr.fileno(), sys.stdout.fileno())
    try:
        code = serve(sys.stdin.buffer, replies)
    except BrokenPipeError:   # the node died while this worker answered: nobody to tell
        os._exit(0)
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
