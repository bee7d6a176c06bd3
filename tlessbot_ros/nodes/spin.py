"""Spinning a node: the executor named by ``sync.executor`` (:func:`make_executor`), a spin
loop that hears signals (:func:`spin_until_interrupted`), and :func:`run_node`, the ``main()`` of
every node."""
from __future__ import annotations

from functools import partial
from typing import Any, NoReturn

from rclpy.node import Node

from tlessbot_ros.core.common.sync import EXECUTORS
from tlessbot_ros.nodes.exit_wait import forget_threads
from tlessbot_ros.nodes.process_setup import init_ros, limit_blas_threads
from tlessbot_ros.nodes.signals import (
    ignore_interrupts_while_stopping,
    interrupts_deferred,
    spin_once_or_interrupt,
)

# between bytecodes, and a wait inside rclpy would hold them off until a message came.
SIGNAL_POLL_S = 0.1


def spin_until_interrupted(node: Node, executor: str = 'single_threaded') -> None:
    """Spin ``node`` in this thread until Ctrl-C, SIGTERM (KeyboardInterrupt, see
    :func:`interrupt_on_signals`) or the context's shutdown, with the ``executor`` named as
    :attr:`~tlessbot_ros.core.common.SyncParams.executor` ('events', 'single_threaded')."""
    import rclpy

    spinner = make_executor(executor, node.context)
    spinner.add_node(node)
    try:
        # A signal raises nothing inside a callback (rclpy would log the KeyboardInterrupt as
        # a FATAL error of that callback): the loop raises it after the turn, within
        # SIGNAL_POLL_S.
        with interrupts_deferred():
            while rclpy.ok(context=node.context):
                spin_once_or_interrupt(partial(spinner.spin_once, timeout_sec=SIGNAL_POLL_S))
    finally:
        spinner.remove_node(node)


def make_executor(kind: str, context: Any) -> Any:
    """An rclpy executor for ``context``, one of :data:`~tlessbot_ros.core.common.sync.EXECUTORS`:
    'events' (rclpy's EventsExecutor, which ignores callback groups: a node that pauses its
    inputs must also cope with messages delivered while paused, as
    :class:`~tlessbot_ros.nodes.inputs.TwoViewInputs` does) or 'single_threaded'; or
    'multi_threaded', for a node whose service calls wait (nodes/objects.py; not a stage's
    ``sync.executor``).

    Spin it with ``spin_once`` (:func:`spin_until_interrupted`): the EventsExecutor's own
    ``spin()`` (rclpy 7.1) fires no timer and, when another thread creates a subscription or a
    publisher meanwhile, loops at 100 % of a core holding the interpreter lock
    (``scripts/events_executor_check.py --how spin``). Its ``spin_once`` loop does neither.

    Raises:
        ValueError: another name.
    """
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    if kind == 'single_threaded':
        from rclpy.executors import SingleThreadedExecutor
        return SingleThreadedExecutor(context=context)
    if kind == 'multi_threaded':   # nodes whose service calls wait (nodes/objects.py)
        from rclpy.executors import MultiThreadedExecutor
        return MultiThreadedExecutor(num_threads=4, context=context)
    raise ValueError(f'executor must be one of {[*EXECUTORS, "multi_threaded"]}, got '
                     f'{kind!r}')


def run_node(node_class: type, args: list[str] | None = None) -> None:
    """``main()`` of every node: init, spin until Ctrl-C or shutdown, clean up (Jazzy style).

    BLAS runs on one thread per node process (:func:`limit_blas_threads`). A
    :class:`~tlessbot_ros.errors.TlessbotError` while constructing the node (a missing model
    file, a bad parameter file) prints one line and exits with code 1. Ctrl-C or SIGTERM, also
    while the node is being constructed, ends it in order with exit code 0: the node is
    destroyed (its ``destroy_node`` joins its threads, which finish the frame in hand) while
    the ROS context is still valid, and only then is the context shut down; the process then
    ends at once (:func:`exit_without_teardown`).
    """
    import sys

    import rclpy
    from rclpy.executors import ExternalShutdownException

    from tlessbot_ros.errors import TlessbotError

    limit_blas_threads()
    init_ros(args)
    try:
        node = node_class()
    except TlessbotError as error:
        print(f'{node_class.__name__}: error: {error}', file=sys.stderr)
        rclpy.try_shutdown()
        sys.exit(1)
    except KeyboardInterrupt:
        rclpy.try_shutdown()
        return
    try:
        spin_until_interrupted(node, getattr(node, 'executor_kind', 'single_threaded'))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        ignore_interrupts_while_stopping()
        node.destroy_node()
        rclpy.try_shutdown()
    exit_without_teardown(0)


def exit_without_teardown(code: int) -> NoReturn:
    """End a node process whose node and ROS context are already shut down: run the atexit
    handlers, flush the output, and exit without clearing every imported module.

    That clearing (scikit-learn, SciPy, Open3D, numba, OpenCV objects, one by one) is most of
    a node's stop, and on a loaded host it can outlast the 5 s ``ros2 launch`` waits after
    SIGINT before it escalates to SIGTERM (docs/bench/code-figures.md).
    """
    import atexit
    import os
    import sys

    forget_threads()   # os._exit ends every thread without unwinding it: none is waited for
    atexit._run_exitfuncs()   # what a normal exit runs first (logging's flush among them)
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):   # a closed or broken pipe: nothing more can be said
            pass
    os._exit(code)
