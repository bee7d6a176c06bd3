"""Parts fitted in worker processes: the same poses as in-process, and a broken worker costs
time, never a pose."""
from __future__ import annotations

import dataclasses
import io
import os
import signal
import time

import numpy as np
import pytest

from tlessbot_ros.core.common import default_rig
from tlessbot_ros.core.pipeline import FitParams, PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import PoseCandidate, PoseParams, TemplateDatabase
from tlessbot_ros.parallel import wire
from tlessbot_ros.parallel.pose_pool import PoseWorkerParams, PoseWorkerPool

SIDE = default_rig()['side']


@pytest.fixture(scope='module')
def scene(part21_seen_from_the_side, tmp_path_factory):
    """Part 21 on the table cut into three instances, so a frame has several parts to share
    out, with the template database saved where the workers load it."""
    db, depth, mask, _ = part21_seen_from_the_side
    path = tmp_path_factory.mktemp('pool') / 'templates.npz'
    db.save(path)
    db = TemplateDatabase.load(path)   # what the workers fit with (saving rounds)
    inputs = {'side': ViewInput(rgb=None, depth_m=depth, intrinsics=SIDE.intrinsics,
                                T_world_camera=SIDE.T_world_camera)}
    labels = mask.astype(np.uint16)
    columns = np.flatnonzero(labels.any(axis=0))
    for k, start in enumerate(np.array_split(columns, 3)):
        labels[:, start[0]:start[-1] + 1] *= k + 1
    classes = {1: (21, 5), 2: (5, 21), 3: (21,)}
    return path, db, inputs, {'side': labels}, classes


# the three instances are pieces of one part: keep every piece (no fragment check), the pool's
# mechanics are under test here
ALL_PIECES = FitParams(fragment_overlap=0.0)
# The pose fallback has no wall-time cap by default (fallback_budget_ms 0), so a part's fit does
# not depend on how busy the process that fits it is (bit-for-bit comparisons).
POSE = PoseParams()


def _slow(pipeline, delay_s=0.3):
    """fit_part of ``pipeline`` that takes at least ``delay_s``, counting its calls: the pool's
    workers must take some jobs while the calling thread sleeps."""
    calls, fit_part = [], pipeline.fit_part

    def fit_here(job):
        calls.append(job.detection.instance_id)
        time.sleep(delay_s)
        fit_part(job)
    return fit_here, calls


def _poses(detections):
    return [(d.instance_id, d.obj_id, d.class_rank, d.pose.T_camera_object.tolist(),
             d.pose.fitness, d.second and d.second.fitness) for d in detections]


def _estimate(pipeline, scene, fitter, fit_here=None):
    _, _, inputs, labels, classes = scene
    done = []
    if fit_here is not None:
        pipeline_fit, pipeline.fit_part = pipeline.fit_part, fit_here
    try:
        detections = pipeline.estimate_poses(inputs, labels, classes, fitter=fitter,
                                             on_detection=lambda d: done.append(d.instance_id))
    finally:
        if fit_here is not None:
            pipeline.fit_part = pipeline_fit
    return detections, done


@pytest.fixture
def pool(scene):
    path = scene[0]
    with PoseWorkerPool(path, pose=POSE, fit=FitParams(),
                        params=PoseWorkerParams(count=1, restart_delay_s=0.0,
                                                         job_timeout_s=1.0)) as pool:
        assert pool.wait_ready(120.0), list(pool.errors)
        yield pool


def test_workers_fit_exactly_what_the_node_fits(scene, pool):
    pipeline = PerceptionPipeline(templates=scene[1], fit_params=ALL_PIECES, pose=POSE)
    alone, _ = _estimate(pipeline, scene, None)
    fit_here, calls = _slow(pipeline)
    shared, done = _estimate(pipeline, scene, pool, fit_here)
    assert len(calls) < 3                        # the worker fitted at least one part
    assert sorted(done) == [1, 2, 3]             # each part handed over once
    assert _poses(shared) == _poses(alone)       # bit for bit, wherever it was fitted
    assert all(d.pose is not None for d in shared)


def test_a_hung_worker_costs_time_not_poses(scene, pool):
    pipeline = PerceptionPipeline(templates=scene[1], fit_params=ALL_PIECES, pose=POSE)
    alone, _ = _estimate(pipeline, scene, None)
    [worker] = pool._workers
    os.kill(worker.process.pid, signal.SIGSTOP)   # alive, but it never answers
    fit_here, calls = _slow(pipeline)
    started = time.monotonic()
    shared, done = _estimate(pipeline, scene, pool, fit_here)
    assert time.monotonic() - started < 3 * 0.3 + pool.params.job_timeout_s + 2.0
    assert sorted(calls) == [1, 2, 3]            # the worker's part was fitted here instead
    assert sorted(done) == [1, 2, 3] and _poses(shared) == _poses(alone)
    assert pool.failures == 1 and 'no answer' in pool.errors[-1]
    # The next frame starts a new worker; once it is ready it takes parts again.
    _estimate(pipeline, scene, pool)
    assert pool.replaced == 1 and pool.failures == 1
    assert pool.wait_ready(120.0) and pool.ready_count == 1
    fit_here, calls = _slow(pipeline)
    shared, _ = _estimate(pipeline, scene, pool, fit_here)
    assert len(calls) < 3 and _poses(shared) == _poses(alone)


def test_a_worker_that_cannot_start_leaves_the_fits_to_the_node(scene, tmp_path):
    pipeline = PerceptionPipeline(templates=scene[1], fit_params=ALL_PIECES, pose=POSE)
    alone, _ = _estimate(pipeline, scene, None)
    # restart_delay_s far longer than the test: "within the delay" must not depend on how
    # fast this host fits the frames below (it failed with the default 5 s under load)
    with PoseWorkerPool(tmp_path / 'missing.npz', pose=PoseParams(), fit=FitParams(),
                        params=PoseWorkerParams(count=1, restart_delay_s=3600.0)) as pool:
        assert not pool.wait_ready(60.0)
        shared, done = _estimate(pipeline, scene, pool)
        assert sorted(done) == [1, 2, 3] and _poses(shared) == _poses(alone)
        assert pool.failures == 1 and 'missing.npz' in pool.errors[-1]
        _estimate(pipeline, scene, pool)         # within restart_delay_s: no new process
        assert pool.replaced == 0 and pool.failures == 1


def test_messages_and_poses_cross_the_pipe_exactly():
    candidate = PoseCandidate(np.linalg.qr(np.random.default_rng(1).normal(size=(4, 4)))[0],
                              np.float32(0.8125), 0.0012345678901234567, 0.3, 'ransac', 4, -1)
    stream = io.BytesIO()
    points = np.random.default_rng(2).normal(size=(7, 3))
    wire.write_message(stream, {'pose': wire.candidate_to_json(candidate)},
                       wire.points_to_bytes(points))
    stream.seek(0)
    header, payload = wire.read_message(stream)
    back = wire.candidate_from_json(header['pose'])
    assert np.array_equal(back.T_camera_object, candidate.T_camera_object)
    assert (back.fitness, back.inlier_rmse_m, back.method) == (0.8125, candidate.inlier_rmse_m,
                                                               'ransac')
    assert np.array_equal(wire.points_from_bytes(payload), points)


@pytest.mark.parametrize('data', [b'', b'\x05\x00\x00\x00{"a"', b'\x03\x00\x00\x00abc',
                                  b'\xff\xff\xff\xff'])
def test_a_broken_message_is_a_wire_error(data):
    with pytest.raises(wire.WireError):
        wire.read_message(io.BytesIO(data))


def test_changed_settings_reach_the_workers_with_their_next_part(scene, pool):
    changed = dataclasses.replace(POSE, icp_iterations=0, planar_iterations=1)
    before = PerceptionPipeline(templates=scene[1], fit_params=ALL_PIECES, pose=POSE)
    after = before.replace(pose=changed)
    old, _ = _estimate(before, scene, None)
    new, _ = _estimate(after, scene, None)
    assert _poses(new) != _poses(old)            # the change shows in the poses
    pool.update(pose=changed, fit=ALL_PIECES)
    fit_here, calls = _slow(after)
    shared, _ = _estimate(after, scene, pool, fit_here)
    assert len(calls) < 3                        # the worker fitted at least one part ...
    assert _poses(shared) == _poses(new)         # ... with the new settings
    fit_here, calls = _slow(after)               # and keeps them for the parts after
    shared, _ = _estimate(after, scene, pool, fit_here)
    assert len(calls) < 3 and _poses(shared) == _poses(new)


def test_the_pool_grows_and_shrinks_between_frames(scene):
    pipeline = PerceptionPipeline(templates=scene[1], fit_params=ALL_PIECES, pose=POSE)
    alone, _ = _estimate(pipeline, scene, None)
    with PoseWorkerPool(scene[0], pose=POSE, fit=FitParams(),
                        params=PoseWorkerParams(count=0)) as pool:
        pool.reconfigure(PoseWorkerParams(count=2))
        assert pool.wait_ready(120.0) and pool.ready_count == 2, list(pool.errors)
        fit_here, calls = _slow(pipeline)
        shared, _ = _estimate(pipeline, scene, pool, fit_here)
        assert len(calls) < 3 and _poses(shared) == _poses(alone)
        workers = list(pool._workers)
        pool.reconfigure(PoseWorkerParams(count=1))
        assert pool._workers == workers[:1]      # the first keeps working
        deadline = time.monotonic() + 30.0
        while workers[1].process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        assert workers[1].process.poll() is not None   # the other one ended
        pool.reconfigure(PoseWorkerParams(count=0))
        shared, done = _estimate(pipeline, scene, pool)   # every part fitted here
        assert sorted(done) == [1, 2, 3] and _poses(shared) == _poses(alone)
        assert pool.worker_fits > 0 and pool.failures == 0


def test_worker_params_are_validated():
    with pytest.raises(ValueError, match='count must be >= 0'):
        PoseWorkerParams(count=-1)
    with pytest.raises(ValueError, match='job_timeout_s must be > 0'):
        PoseWorkerParams(job_timeout_s=0.0)


def _alive(pid: int) -> bool:
    """The process exists and is no zombie (an orphan's zombie waits for init to reap it)."""
    try:
        with open(f'/proc/{pid}/stat') as stat:
            return stat.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def _wait_gone(pid: int, timeout_s: float = 60.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    return not _alive(pid)


def _start_node(code: str, log) -> tuple[object, int]:
    """A stand-in node process running ``code``, which prints its worker's pid first."""
    import subprocess
    import sys

    node = subprocess.Popen([sys.executable, '-c', code], stdout=subprocess.PIPE,
                            stderr=log, text=True)
    return node, int(node.stdout.readline())


def test_a_busy_worker_ends_when_its_node_is_killed(tmp_path):
    """Busy (here: asleep, as in a long fit) a worker does not read its input, so the end of it
    cannot tell it that its node died: it must notice on its own."""
    busy_worker = ('import sys, time\n'
                   'from tlessbot_ros.parallel.pose_worker import exit_with_parent\n'
                   'exit_with_parent(int(sys.argv[1]))\ntime.sleep(300)\n')
    node, worker = _start_node(
        'import os, subprocess, sys, time\n'
        f'worker = subprocess.Popen([sys.executable, "-c", {busy_worker!r}, str(os.getpid())])\n'
        'print(worker.pid, flush=True)\ntime.sleep(300)\n', None)
    try:
        assert _alive(worker)
        node.kill()
        node.wait()
        assert _wait_gone(worker)
    finally:
        node.kill()


def test_a_pool_leaves_no_worker_behind_when_its_node_is_killed(tmp_path):
    """SIGKILL (or the OOM killer) gives the node no chance to stop its workers: each ends by
    itself, quietly, whether it was loading its templates or waiting for a part."""
    log = tmp_path / 'node.log'
    with open(log, 'w') as stream:
        node, worker = _start_node(
            'import time\nfrom tlessbot_ros.data import DEFAULT_TEMPLATES\n'
            'from tlessbot_ros.core.pipeline import FitParams\n'
            'from tlessbot_ros.core.pose import PoseParams\n'
            'from tlessbot_ros.parallel.pose_pool import PoseWorkerParams, PoseWorkerPool\n'
            'pool = PoseWorkerPool(DEFAULT_TEMPLATES, pose=PoseParams(), fit=FitParams(), '
            'params=PoseWorkerParams(count=1))\n'
            'print(pool._workers[0].process.pid, flush=True)\ntime.sleep(300)\n', stream)
    try:
        node.kill()   # the worker is still importing or loading its templates
        node.wait()
        assert _wait_gone(worker)
        assert 'Traceback' not in log.read_text()
    finally:
        node.kill()


def test_a_worker_builds_no_lookalike_check(scene):
    """The node checks look-alikes on the fitted poses (every view); a worker only fits, so it
    must not build and warm up the check's meshes, also after new settings."""
    from tlessbot_ros.parallel.pose_worker import pipeline_from_config, with_settings

    path, db = scene[0], scene[1]
    assert PerceptionPipeline(templates=db, fit_params=FitParams()).lookalike is not None
    worker = pipeline_from_config({'templates': str(path), 'fit': {'lookalike_check': True}})
    assert worker.lookalike is None
    changed = with_settings(worker, {'fit': {'lookalike_tolerance_m': 0.003}})
    assert changed.lookalike is None and changed.fit_params.lookalike_tolerance_m == 0.003
