"""The thread that processes a stage's frames (``sync.worker_thread``, on by default).

The executor thread only takes messages and pairs them; :class:`FrameWorker` runs the stage on
its own thread. A frame that completes while the worker is busy becomes the single pending
frame, and a newer one replaces it, so a slow stage always starts on the newest frame. Frames
released together at a time jump are all kept, in order. Jobs (the warm-up, a tool's call) run
on the same thread before the next frame (:meth:`FrameWorker.on_frame_thread`).

Without a worker thread a frame is processed on the caller's (executor) thread at once.

An interpreter's exit waits for the job or frame in hand on these threads
(:mod:`~tlessbot_ros.nodes.exit_wait`): a daemon thread still in OpenCV or numba's compiler when
the interpreter finalises aborts the process.
"""
from __future__ import annotations

import threading
import time
import traceback
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from functools import partial
from typing import Any

from tlessbot_ros.nodes.exit_wait import wait_at_exit
from tlessbot_ros.nodes.inputs import Views


class FrameWorker:
    """A stage's frame thread: the pending frame, the frames held at a time jump, jobs.

    Args:
        name: the thread's name.
        handle: processes one frame (``views``); it must not raise.
        before_frame: called before each frame (the live parameters are applied there, so a
            frame sees all of a change or nothing).
        threaded: run a thread; False: :meth:`submit` processes the frame at once.
    """

    def __init__(self, name: str, handle: Callable[[Views], None],
                 before_frame: Callable[[], None], *, threaded: bool = True) -> None:
        self._handle, self._before_frame = handle, before_frame
        self._name = name
        # the lock of the frame state; the node's setup and parameter changes take it too
        self.lock = threading.Condition()
        self.stopping = False
        self.busy = False
        self._pending: Views | None = None
        # frames released together at a time jump (at most jump_confirmations + 1 at a time)
        self._held: deque[Views] = deque()
        self._jobs: deque[tuple[Callable[[], Any], Future]] = deque()
        self.thread: threading.Thread | None = None
        if threaded:
            self.thread = threading.Thread(target=self._work, name=name, daemon=True)
            self.thread.start()
            wait_at_exit(self.thread, stop=partial(self.stop, join=False))

    def submit(self, views: Views, *, held: bool = False) -> Views | None:
        """Hand over an admitted frame; returns the pending frame it replaced (dropped), if
        any. ``held`` frames (released at a time jump) are queued, none replaced."""
        if self.thread is None:
            self._before_frame()
            self._handle(views)
            return None
        with self.lock:
            replaced = None
            if held:
                self._held.append(views)
            else:
                replaced, self._pending = self._pending, views
            self.lock.notify()
        return replaced

    def on_frame_thread(self, job: Callable[[], Any]) -> Future:
        """Run ``job`` on the frame thread before the next frame; the Future gives its result
        (cancelled if the worker stops first). Without a thread, on a thread of its own."""
        done: Future = Future()
        if self.thread is None:
            thread = threading.Thread(target=_run_job, args=(job, done), daemon=True,
                                      name=f'{self._name}_job')
            thread.start()
            wait_at_exit(thread)
            return done
        with self.lock:
            if self.stopping:
                done.cancel()
            else:
                self._jobs.append((job, done))
                self.lock.notify_all()
        return done

    def when_warm(self, warm_up: Callable[[], None], ready: Callable[[float], None],
                  failed: Callable[[str, str], None]) -> None:
        """Run ``warm_up`` on the frame thread, then ``ready(warm_up_s)`` under :attr:`lock`
        unless the worker stopped meanwhile (Ctrl-C: nothing is set up halfway). A failure of
        either calls ``failed(message, traceback)`` under the lock (never raised into a dead
        thread)."""
        def run() -> None:
            started = time.monotonic()
            try:
                warm_up()
            except Exception as error:  # reported, never raised into a dead thread
                with self.lock:
                    failed(f'warm-up failed: {type(error).__name__}: {error}',
                           traceback.format_exc())
                return
            with self.lock:
                if not self.stopping:
                    ready(time.monotonic() - started)

        def report(done: Future) -> None:   # ready() failed: said, as a warm-up failure
            if not done.cancelled() and done.exception() is not None:
                error = done.exception()
                with self.lock:
                    failed(f'start-up failed: {type(error).__name__}: {error}',
                           ''.join(traceback.format_exception(error)))

        self.on_frame_thread(run).add_done_callback(report)

    def wait_idle(self, timeout_s: float = 10.0) -> bool:
        """Block until no frame is pending or in hand; False on timeout."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self.lock:
                if self._pending is None and not self._held and not self.busy:
                    return True
            time.sleep(0.005)
        return False

    def stop(self, *, join: bool) -> None:
        """Stop taking frames and jobs (queued jobs are cancelled); with ``join``, wait for
        the frame in hand to finish (up to 30 s)."""
        with self.lock:
            self.stopping = True
            for _, done in self._jobs:
                done.cancel()
            self._jobs.clear()
            self.lock.notify_all()
        if join and self.thread is not None and self.thread is not threading.current_thread():
            self.thread.join(timeout=30.0)

    def _next(self) -> tuple[Views | None, tuple[Callable[[], Any], Future] | None]:
        """Wait for a job or a frame (caller holds the lock); (None, None): stopping."""
        while (self._pending is None and not self._held and not self._jobs
               and not self.stopping):
            self.lock.wait()
        if self.stopping:
            return None, None
        if self._jobs:   # the warm-up, a tool's call: before any frame
            return None, self._jobs.popleft()
        if self._held:   # older than any pending frame: first, in order
            views = self._held.popleft()
        else:
            views, self._pending = self._pending, None
        self.busy = True
        return views, None

    def _work(self) -> None:
        while True:
            with self.lock:
                views, job = self._next()
            if job is not None:
                _run_job(*job)
                continue
            if views is None:
                return
            try:
                self._before_frame()   # between frames: a frame sees all or nothing
                self._handle(views)
            finally:
                self.busy = False


def _run_job(job: Callable[[], Any], done: Future) -> None:
    """Run ``job`` into ``done`` (a job cancelled meanwhile is skipped)."""
    if not done.set_running_or_notify_cancel():
        return
    try:
        done.set_result(job())
    except BaseException as error:  # the caller of on_frame_thread gets it from the Future
        done.set_exception(error)
