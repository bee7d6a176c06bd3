"""Fit the parts of a frame at the same time: the calling thread and N worker processes.

A worker is ``python -m tlessbot_ros.parallel.pose_worker`` holding its own copy of the
template database; it fits exactly what :meth:`PerceptionPipeline.fit_part` fits in-process,
so the answers do not depend on who fitted a part. Jobs are handed out one at a time to
whoever is free (the calling thread included), and each part is reported the moment it is
done. A worker that dies, answers with an error or stays silent for ``job_timeout_s`` is
replaced (in the background), and its part is fitted in the calling process instead: a broken
worker costs time, never a pose.
"""
from __future__ import annotations

import os
import select
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tlessbot_ros.core.pipeline import FitParams, PartJob
from tlessbot_ros.core.pose import PoseParams
from tlessbot_ros.parallel.spare_cpu import read_process_cpu_s
from tlessbot_ros.parallel.wire import (
    WireError,
    candidate_from_json,
    encode_message,
    matrix_to_json,
    params_to_json,
    points_to_bytes,
    read_message,
    write_message,
)


@dataclass(frozen=True)
class PoseWorkerParams:
    """Worker processes of the pose stage.

    Attributes:
        count: worker processes besides the node's own thread (>= 0; 0: parts are fitted in the
            node); each holds its own templates.
        job_timeout_s: a worker silent for this long on one part is replaced, and the part is
            fitted in the node.
        start_timeout_s: a worker not ready this long after its start (loading the templates,
            building the caches) is given up and started again.
        restart_delay_s: a failed worker is started again at most this often (a worker that
            cannot start must not cost a process start per frame).
    """

    count: int = 0
    job_timeout_s: float = 5.0
    start_timeout_s: float = 120.0
    restart_delay_s: float = 5.0

    def __post_init__(self) -> None:
        if self.count < 0:
            raise ValueError(f'count must be >= 0 (0: no worker processes), got {self.count}')
        for name in ('job_timeout_s', 'start_timeout_s'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0 s, got {getattr(self, name)}')
        if not self.restart_delay_s >= 0:
            raise ValueError(f'restart_delay_s must be >= 0 s, got {self.restart_delay_s}')


class _Worker:
    """One worker process and its pipes (used by one thread at a time)."""

    def __init__(self, config: dict[str, Any]) -> None:
        self.settings = config   # the pool's config whose pose and fit settings it fits with
        self.process = subprocess.Popen(
            [sys.executable, '-m', 'tlessbot_ros.parallel.pose_worker', str(os.getpid())],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=_worker_environment())
        self.started = time.monotonic()
        self.ready = threading.Event()
        self.failed = ''
        self.reported = False   # its failure is in the pool's errors
        self._next_job = 0
        self._start_thread = threading.Thread(target=self._start, args=(config,), daemon=True,
                                              name='pose_worker_start')
        self._start_thread.start()

    def _start(self, config: dict[str, Any]) -> None:
        try:
            write_message(self.process.stdin, config)
            header, _ = read_message(self.process.stdout)
        except (WireError, OSError) as error:
            self.failed = f'pose worker did not start: {error}'
            return
        if 'ready' in header:
            self.ready.set()
        else:
            self.failed = f'pose worker did not start: {header.get("error", header)}'

    @property
    def alive(self) -> bool:
        return self.process.poll() is None and not self.failed

    def fit(self, job: PartJob, timeout_s: float, settings: dict[str, Any]) -> bool:
        """Fit ``job`` in the worker (fills its detection) with the pose and fit settings of
        ``settings`` (sent along when they are not the worker's yet); False if the worker
        failed."""
        self._next_job += 1
        deadline = time.monotonic() + timeout_s
        header = {'job': self._next_job, 'candidates': list(job.candidates),
                  'T_world_camera': matrix_to_json(job.T_world_camera)}
        if job.box_camera is not None:   # box mode: the box and its camera matrix
            header['box'] = [int(v) for v in job.detection.box]
            header['box_camera'] = matrix_to_json(job.box_camera)
        if settings is not self.settings:
            header['params'] = {'pose': settings['pose'], 'fit': settings['fit']}
        try:
            self._send(encode_message(header, points_to_bytes(job.points)), deadline)
            ready, _, _ = select.select([self.process.stdout], [], [],
                                        max(0.0, deadline - time.monotonic()))
            if not ready:
                raise WireError(f'no answer within {timeout_s:.1f} s')
            header, _ = read_message(self.process.stdout)
        except (WireError, OSError, ValueError) as error:
            self.failed = f'pose worker failed: {error}'
            return False
        if header.get('job') != self._next_job:
            self.failed = 'pose worker failed: answer out of order'
            return False
        if 'error' in header:
            return False  # this part failed, not the worker: it is fitted again in the node
        self.settings = settings
        detection = job.detection
        detection.obj_id, detection.class_rank = int(header['obj_id']), int(header['class_rank'])
        detection.pose = candidate_from_json(header['pose'])
        detection.second = candidate_from_json(header['second'])
        return True

    def _send(self, data: bytes, deadline: float) -> None:
        """Write ``data`` to the worker's stdin, giving up at ``deadline`` (a worker that
        stopped reading must not block the node)."""
        fd = self.process.stdin.fileno()
        os.set_blocking(fd, False)
        view = memoryview(data)
        while view:
            _, writable, _ = select.select([], [fd], [], max(0.0, deadline - time.monotonic()))
            if not writable:
                raise WireError('the worker stopped reading')
            try:
                view = view[os.write(fd, view):]
            except BlockingIOError:
                continue

    def stop(self, timeout_s: float = 2.0) -> None:
        try:
            if self.process.stdin:
                self.process.stdin.close()  # the worker ends at the end of its input
            self.process.wait(timeout=timeout_s)
        except (OSError, subprocess.TimeoutExpired):
            self.process.kill()
            self.process.wait()
        if self.process.stdout:
            self.process.stdout.close()


def _worker_environment() -> dict[str, str]:
    """The node's environment, with this package importable from the worker."""
    env = dict(os.environ)
    package_root = str(Path(__file__).resolve().parents[2])
    paths = [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p]
    env['PYTHONPATH'] = os.pathsep.join([package_root, *paths])
    return env


class PoseWorkerPool:
    """A :class:`~tlessbot_ros.core.pipeline.PartFitter` over worker processes.

    Example:
        >>> pool = PoseWorkerPool('templates.npz', pose=PoseParams(),
        ...                       fit=FitParams(), params=PoseWorkerParams(count=1))
        >>> pipeline.estimate_poses(views, labels, classes, fitter=pool)
        >>> pool.close()

    Workers start in the background; until one is ready, its share is fitted in-process.
    ``errors`` lists what went wrong with workers (the node logs it).
    """

    def __init__(self, templates_path: str | Path, *, pose: PoseParams,
                 fit: FitParams, params: PoseWorkerParams) -> None:
        self.params = params
        self._config = {'templates': str(templates_path), 'pose': params_to_json(pose),
                        'fit': params_to_json(fit)}
        self._workers = [_Worker(self._config) for _ in range(params.count)]
        self.errors: deque[str] = deque(maxlen=20)   # the latest, for the logs
        self.failures = 0
        self.replaced = 0
        self.worker_fits = 0   # parts fitted by workers

    def wait_ready(self, timeout_s: float | None = None) -> bool:
        """Block until every worker is ready (True) or one failed or the time ran out."""
        deadline = time.monotonic() + (self.params.start_timeout_s if timeout_s is None
                                       else timeout_s)
        for worker in self._workers:
            while not worker.ready.wait(0.05):
                if worker.failed or worker.process.poll() is not None:
                    self._report(worker, 'pose worker exited while starting')
                    return False
                if time.monotonic() > deadline:
                    return False
        return True

    def cpu_seconds(self) -> float:
        """CPU time the current workers have used so far, seconds (a replaced worker's
        is no longer counted)."""
        return sum(read_process_cpu_s(w.process.pid) or 0.0 for w in self._workers)

    @property
    def ready_count(self) -> int:
        return sum(w.ready.is_set() and w.alive for w in self._workers)

    def fit_all(self, jobs: Sequence[PartJob], fit_here: Callable[[PartJob], None],
                on_done: Callable[[PartJob], None]) -> None:
        """Fit ``jobs`` here and in every ready worker at once; ``on_done`` is called once per
        job, as it finishes, under a lock. Errors raised by ``fit_here`` or ``on_done`` are
        raised here after every job has been handled."""
        self._replace_failed()
        pending = deque(jobs)
        take_lock, done_lock = threading.Lock(), threading.Lock()
        raised: list[BaseException] = []

        def take() -> PartJob | None:
            with take_lock:
                return pending.popleft() if pending else None

        def finish(job: PartJob) -> None:
            try:
                with done_lock:
                    on_done(job)
            except BaseException as error:  # handed to the caller after the join
                raised.append(error)

        def fit_and_finish(job: PartJob) -> None:
            try:
                fit_here(job)
            except BaseException as error:
                raised.append(error)
                return
            finish(job)

        def serve(worker: _Worker) -> None:
            while worker.alive and (job := take()) is not None:
                if worker.fit(job, self.params.job_timeout_s, self._config):
                    self.worker_fits += 1
                    finish(job)
                    continue
                if worker.failed:
                    self._report(worker, worker.failed)
                with take_lock:  # fitted again by the calling thread (one fit at a time)
                    pending.appendleft(job)

        threads = [threading.Thread(target=serve, args=(w,), daemon=True, name='pose_job')
                   for w in self._workers if w.ready.is_set() and w.alive]
        for thread in threads:
            thread.start()
        while (job := take()) is not None:
            fit_and_finish(job)
        for thread in threads:
            thread.join()
        while (job := take()) is not None:  # handed back by a failed worker
            fit_and_finish(job)
        if raised:
            raise raised[0]

    def update(self, *, pose: PoseParams, fit: FitParams) -> None:
        """New pose and fit settings: each worker gets them with its next part, a worker
        started later at its start. Call between frames (not during :meth:`fit_all`)."""
        self._config = {**self._config, 'pose': params_to_json(pose),
                        'fit': params_to_json(fit)}

    def reconfigure(self, params: PoseWorkerParams) -> None:
        """New pool settings; workers are started or stopped to make ``params.count`` (new
        ones take parts once ready; stopped ones end in the background). Call between
        frames (not during :meth:`fit_all`)."""
        self.params = params
        while len(self._workers) < params.count:
            self._workers.append(_Worker(self._config))
        surplus, self._workers = self._workers[params.count:], self._workers[:params.count]
        for worker in surplus:
            threading.Thread(target=worker.stop, daemon=True, name='pose_worker_stop').start()

    def _replace_failed(self) -> None:
        """Record why a worker is dead, failed or stuck in its start, and start a new one in
        its place (at most every ``restart_delay_s``; it joins once ready)."""
        now = time.monotonic()
        for k, worker in enumerate(self._workers):
            stuck = not worker.ready.is_set() and \
                now - worker.started > self.params.start_timeout_s
            if worker.alive and not stuck:
                continue
            code = worker.process.poll()
            self._report(worker, f'pose worker exited with code {code}' if code is not None
                         else f'pose worker not ready after {self.params.start_timeout_s:.0f} s')
            if now - worker.started < self.params.restart_delay_s:
                continue
            worker.stop(timeout_s=0.0)
            self._workers[k] = _Worker(self._config)
            self.replaced += 1

    def _report(self, worker: _Worker, why: str) -> None:
        """Count and keep a worker's failure once (its own message when it has one)."""
        if not worker.reported:
            worker.reported = True
            self.errors.append(worker.failed or why)
            self.failures += 1

    def close(self) -> None:
        """Stop every worker."""
        for worker in self._workers:
            worker.stop()
        self._workers = []

    def __enter__(self) -> PoseWorkerPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
