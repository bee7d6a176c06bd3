"""Threads that run native code are finished before the interpreter finalises.

A stage's frame thread runs OpenCV, numba's compiler (LLVM through ctypes) and BLAS with the
GIL released. It is a daemon thread, so a node destroyed during its warm-up (Ctrl-C at
start-up, a test that only builds nodes) returns at once and the process can end while it
still runs. CPython before 3.14 then ends such a thread with ``pthread_exit()`` when it takes the
GIL back after finalisation began (``PyEval_RestoreThread``); the forced unwind that starts
there aborts the whole process (SIGABRT, exit status 134, "FATAL: exception not rethrown" or
"terminate called without an active exception") when it crosses a C++ frame that catches it
without rethrowing or may not throw, such as the ``catch (...)`` of every OpenCV binding
(https://github.com/python/cpython/issues/87135; the C++ side: https://github.com/swig/swig/pull/2413).

:func:`wait_at_exit` registers a thread: an :mod:`atexit` function, which runs while the
interpreter is still whole, asks each registered thread that is alive to stop and waits for
it, up to :data:`EXIT_WAIT_S` for all of them together, before finalisation starts. A process
that ends with ``os._exit`` (a node's :func:`~tlessbot_ros.nodes.spin.run_node`) never
finalises: it calls :func:`forget_threads` first and ends at once.
"""
from __future__ import annotations

import atexit
import threading
import time
from collections.abc import Callable

# Long enough for the warm-ups of several stages that compile every numba kernel at once on
# a loaded host; a thread stuck for longer is left to be cut off.
EXIT_WAIT_S = 300.0

_lock = threading.Lock()
_threads: list[tuple[threading.Thread, Callable[[], None] | None]] = []


def wait_at_exit(thread: threading.Thread, stop: Callable[[], None] | None = None) -> None:
    """Have the interpreter's exit call ``stop`` (when given: it must ask ``thread`` to end
    and return at once) and then wait for the started ``thread`` to end.

    The exit function is registered again at each call, after the modules the thread runs
    were imported, so that it runs before their own exit functions (numba's among them:
    :mod:`atexit` runs them last in, first out).
    """
    with _lock:
        _threads[:] = [(t, s) for t, s in _threads if t.is_alive()]
        _threads.append((thread, stop))
        atexit.unregister(finish_threads)
        atexit.register(finish_threads)


def finish_threads(timeout_s: float = EXIT_WAIT_S) -> None:
    """Ask every registered thread that is alive to stop, then wait up to ``timeout_s`` (s,
    >= 0) for all of them together. Runs at interpreter exit; one still alive then is left."""
    with _lock:
        threads = [(t, s) for t, s in _threads if t.is_alive()]
    for _, stop in threads:
        if stop is not None:
            stop()
    deadline = time.monotonic() + timeout_s
    for thread, _ in threads:
        thread.join(max(0.0, deadline - time.monotonic()))


def forget_threads() -> None:
    """Wait for no registered thread at exit: for a process about to end with ``os._exit``,
    which stops every thread at once and runs no finalisation."""
    with _lock:
        _threads.clear()
