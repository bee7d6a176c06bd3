"""Ctrl-C and SIGTERM in a ROS process: the main thread stops spinning and shuts down in order.

The only process-wide state of the package lives here: the signals received
(``_SIGNALS_RECEIVED``) and how deep the main thread is in :func:`interrupts_deferred`
(``_DEFERRING``). Spin loops call :func:`raise_if_interrupted` or
:func:`spin_once_or_interrupt`; :func:`quiet_half_built_futures` is the ``sys.unraisablehook``
that keeps a clean exit quiet.
"""
from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

# Signals :func:`interrupt_on_signals` turned into KeyboardInterrupt (the first one only).
_SIGNALS_RECEIVED: list[int] = []
# How many :func:`interrupts_deferred` blocks the main thread is in.
_DEFERRING = [0]


@contextmanager
def interrupts_deferred() -> Iterator[None]:
    """Run a block that must not be cut in half: a signal that comes inside it raises no
    KeyboardInterrupt there; the spin loop's :func:`raise_if_interrupted` raises it after the
    turn. ``tlessbot record`` writes each message inside one, since an interrupt that landed
    inside the mcap writer's ``add_message`` left a half-written record in the chunk, and the
    bag closed on Ctrl-C could not be read back ("unpack requires a buffer of 22 bytes", seen
    once in CI)."""
    _DEFERRING[0] += 1
    try:
        yield
    finally:
        _DEFERRING[0] -= 1


def raise_if_interrupted() -> None:
    """Raise KeyboardInterrupt if SIGINT or SIGTERM came. Spin loops call it after each
    wait: the handler's KeyboardInterrupt is lost when it lands inside a finaliser (Python
    prints "Exception ignored in: <function Future.__del__ ...>" and goes on), and the tool
    would then never stop (seen once in `tlessbot record`)."""
    if _SIGNALS_RECEIVED:
        raise KeyboardInterrupt


def spin_once_or_interrupt(spin_once: Callable[[], Any]) -> None:
    """Run one executor turn (``spin_once``), then :func:`raise_if_interrupted`.

    A signal's KeyboardInterrupt that lands inside a pybind11 call of that turn (rclpy
    converting a message it takes) comes out of it as a RuntimeError ("Unable to convert call
    argument '0' to Python object"; seen once in ``tlessbot echo`` stopped by Ctrl-C while
    poses poured in). After a signal, that error is the interrupt.
    """
    try:
        spin_once()
    except RuntimeError:
        if _SIGNALS_RECEIVED:
            raise KeyboardInterrupt from None
        raise
    raise_if_interrupted()


def interrupt_on_signals() -> bool:
    """Make SIGINT and SIGTERM raise KeyboardInterrupt in the main thread, once (after the
    block, if it comes inside :func:`interrupts_deferred`).

    rclpy's own handlers shut the ROS context down from their thread the moment a signal comes:
    a worker thread still publishing a frame, or logging, then fails ("publisher's context is
    invalid", "Failed to publish log message to rosout"). Here the main thread stops spinning
    and shuts down in order (threads joined, nodes destroyed, then the context). A signal that
    comes while that runs is ignored: after Ctrl-C in a terminal a node gets SIGINT from the
    terminal and again from ``tlessbot launch`` or ``ros2 launch``. Does nothing (False) off the
    main thread, where Python cannot set signal handlers.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return False

    def on_signal(signum: int, frame: object) -> None:
        if not _SIGNALS_RECEIVED:
            _SIGNALS_RECEIVED.append(signum)
            if not _DEFERRING[0]:
                raise KeyboardInterrupt

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, on_signal)
    sys.unraisablehook = quiet_half_built_futures
    return True


_DEFAULT_UNRAISABLEHOOK = sys.unraisablehook   # the hook in place when this module loaded
# rclpy's finalisers that fail on an object whose __init__ a KeyboardInterrupt cut short
_HALF_BUILT_FINALISERS = ('Future.__del__', 'Task.__del__')


def quiet_half_built_futures(unraisable: Any) -> None:
    """``sys.unraisablehook``: after a signal, drop the error of an rclpy Future or Task whose
    construction the signal's KeyboardInterrupt interrupted, and that KeyboardInterrupt
    itself where it landed inside their finaliser; pass anything else on.

    The KeyboardInterrupt of :func:`interrupt_on_signals` can land inside rclpy's
    ``Task.__init__`` before its fields exist; the interrupt itself goes on as usual, but the
    half-built object's finaliser then fails (``AttributeError: 'Task' object has no attribute
    '_exception'``) and Python prints a traceback on a clean exit (seen once in
    `tlessbot record` under SIGTERM: exit 0, the bag complete). It can also land inside
    ``Future.__del__``: Python prints it as ignored, and the spin loop's
    :func:`raise_if_interrupted` raises it after the turn."""
    function = getattr(unraisable.object, '__qualname__', '')
    if (_SIGNALS_RECEIVED
            and isinstance(unraisable.exc_value, (AttributeError, KeyboardInterrupt))
            and function in _HALF_BUILT_FINALISERS
            and getattr(unraisable.object, '__module__', '').startswith('rclpy')):
        return
    _DEFAULT_UNRAISABLEHOOK(unraisable)


def ignore_interrupts_while_stopping() -> None:
    """Ignore SIGINT from now on (call from the main thread when the clean-up starts).

    Ctrl-C in a terminal reaches every process of ``ros2 launch``'s process group, and launch
    then sends each node SIGINT again: that second one would abort the clean-up with a
    KeyboardInterrupt traceback and a non-zero exit. SIGTERM still stops a stuck clean-up.
    """
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
