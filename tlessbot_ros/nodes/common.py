"""Small rclpy helpers shared by the nodes and the ROS-facing tools.

- QoS profiles: sensor data in (best effort, shallow), results out (reliable, depth 10).
- Parameter declaration from a core ``*Params`` dataclass, so code and YAML share one truth
  (:func:`declare_from_dataclass`; :mod:`tlessbot_ros.nodes.parameters` makes them live).
- ``message_class`` (rclpy class by ROS type name), re-exported from
  :mod:`tlessbot_ros.conversions.messages`.
- :func:`init_ros`: ``rclpy.init`` with the package's Fast DDS profile (config/fastdds.xml)
  and glibc's allocator told to keep image-sized buffers (:func:`keep_freed_buffers`); Ctrl-C
  and SIGTERM end the process in order (:func:`interrupt_on_signals`).
"""
from __future__ import annotations

import dataclasses
import os
import sys
from collections.abc import Callable, Collection, Iterator
from contextlib import contextmanager
from functools import partial
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from tlessbot_ros.conversions.messages import message_class  # noqa: F401 (re-exported)
from tlessbot_ros.core.common.sync import EXECUTORS

SENSOR_QOS = qos_profile_sensor_data
RESULT_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                        history=HistoryPolicy.KEEP_LAST, depth=10)


READ_ONLY_NOTE = '(read-only: set it at start-up)'


DDS_PROFILE_VARIABLES = ('FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE')


def use_package_dds_profile(environ: dict[str, str] | None = None) -> str | None:
    """Point Fast DDS at config/fastdds.xml (large shared-memory segments, so camera images
    are not fragmented and repaired), unless the user chose a profile or another middleware.

    Must run before the process's first ``rclpy.init``; child processes inherit it through
    ``environ`` (default ``os.environ``). Returns the profile path set, or None.
    """
    from tlessbot_ros.io.config import package_path

    environ = os.environ if environ is None else environ
    if any(environ.get(name) for name in DDS_PROFILE_VARIABLES):
        return None
    if 'fastrtps' not in environ.get('RMW_IMPLEMENTATION', 'rmw_fastrtps_cpp'):
        return None
    profile = package_path('config', 'fastdds.xml')
    if not profile.is_file():
        return None
    for name in DDS_PROFILE_VARIABLES:
        environ[name] = str(profile)
    return str(profile)


# mallopt(3) parameters of glibc's malloc.h.
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
MALLOC_VARIABLES = ('MALLOC_MMAP_THRESHOLD_', 'MALLOC_TRIM_THRESHOLD_')


def keep_freed_buffers(*, mmap_threshold: int = 32 << 20, trim_threshold: int = 64 << 20,
                       environ: dict[str, str] | None = None) -> bool:
    """Make glibc's malloc serve image-sized blocks from the heap and keep freed memory.

    Every received image (0.6-0.9 MiB) passes through a few freshly allocated buffers (the
    middleware's copy, the serialised bytes, numpy arrays). By default glibc maps blocks this
    large with mmap, or trims the heap once they are freed, so each message pays for new
    zero-filled pages: measured here (4 camera topics at 30 fps into one process), 1.5-1.7 ms
    of CPU per image, against 0.75-0.84 ms with this setting. Memory freed stays with the
    process, up to ``trim_threshold`` bytes above what it uses.

    Does nothing (returns False) off glibc or when the user set MALLOC_MMAP_THRESHOLD_ or
    MALLOC_TRIM_THRESHOLD_ (mallopt would override their choice).
    """
    import ctypes

    environ = os.environ if environ is None else environ
    if any(name in environ for name in MALLOC_VARIABLES):
        return False
    try:
        libc = ctypes.CDLL('libc.so.6')
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, int(mmap_threshold))
                and mallopt(_M_TRIM_THRESHOLD, int(trim_threshold)))


def init_ros(args: list[str] | None = None) -> None:
    """``rclpy.init`` after :func:`use_package_dds_profile` and :func:`keep_freed_buffers`,
    with :func:`interrupt_on_signals` instead of rclpy's signal handlers."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    use_package_dds_profile()
    keep_freed_buffers()
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    interrupt_on_signals()


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
    construction the signal's KeyboardInterrupt interrupted; pass anything else on.

    The KeyboardInterrupt of :func:`interrupt_on_signals` can land inside rclpy's
    ``Task.__init__`` before its fields exist; the interrupt itself goes on as usual, but the
    half-built object's finaliser then fails (``AttributeError: 'Task' object has no attribute
    '_exception'``) and Python prints a traceback on a clean exit (seen once in
    `tlessbot record` under SIGTERM: exit 0, the bag complete)."""
    function = getattr(unraisable.object, '__qualname__', '')
    if (_SIGNALS_RECEIVED and isinstance(unraisable.exc_value, AttributeError)
            and function in _HALF_BUILT_FINALISERS
            and getattr(unraisable.object, '__module__', '').startswith('rclpy')):
        return
    _DEFAULT_UNRAISABLEHOOK(unraisable)


# How often the spinning main thread looks for a signal: Python runs its signal handlers only
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
        while rclpy.ok(context=node.context):
            spin_once_or_interrupt(partial(spinner.spin_once, timeout_sec=SIGNAL_POLL_S))
    finally:
        spinner.remove_node(node)


def make_executor(kind: str, context: Any) -> Any:
    """An rclpy executor for ``context``, one of :data:`~tlessbot_ros.core.common.sync.EXECUTORS`:
    'events' (rclpy's EventsExecutor, which ignores callback groups: a node that pauses its
    inputs must also cope with messages delivered while paused, as
    :class:`~tlessbot_ros.nodes.inputs.TwoViewInputs` does) or 'single_threaded'.

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
    raise ValueError(f'executor must be one of {list(EXECUTORS)}, got {kind!r}')


def attribute_docs(cls: type) -> dict[str, str]:
    """Field descriptions from a dataclass docstring's ``Attributes:`` section.

    Handles ``name: text`` entries, continuation lines, and ``a, b, c: text`` groups.
    """
    docs: dict[str, str] = {}
    lines = (cls.__doc__ or '').splitlines()
    try:
        start = next(i for i, line in enumerate(lines) if line.strip() == 'Attributes:')
    except StopIteration:
        return docs
    current: list[str] = []
    indent = None
    for line in lines[start + 1:]:
        if not line.strip():
            continue
        width = len(line) - len(line.lstrip())
        if indent is None:
            indent = width
        if width < indent:
            break
        if width == indent and ':' in line:
            names, text = line.strip().split(':', 1)
            current = [n.strip() for n in names.split(',')]
            for name in current:
                docs[name] = text.strip()
        else:
            for name in current:
                docs[name] = f'{docs[name]} {line.strip()}'.strip()
    return docs


def declare_parameter(node: Node, name: str, default: Any, descriptor: ParameterDescriptor
                      ) -> Any:
    """``node.declare_parameter(...).value``; a value of another type than the default's (from
    a parameter file or ``-p``) is one clear error, as rcl refuses it.

    Raises:
        TlessbotError: the wrong type (the node stops with one line, :func:`run_node`).
    """
    from rclpy.exceptions import InvalidParameterTypeException

    from tlessbot_ros.errors import TlessbotError

    try:
        return node.declare_parameter(name, default, descriptor).value
    except InvalidParameterTypeException as error:
        raise TlessbotError(f'{node.get_name()}: {str(error).rsplit(":", 1)[0]} (write a double '
                            'with a decimal point, 2.0 not 2, also in lists)') from None


def parameter_value(default: Any, value: Any) -> Any:
    """A declared parameter's value as the dataclass field holding ``default`` wants it: a
    tuple for a tuple field, a list for a list (rclpy hands arrays over as ``array.array``)."""
    if isinstance(default, tuple):
        return tuple(value)
    if isinstance(default, list):
        return list(value)
    return value


def dataclass_parameter_names(params: Any, *, prefix: str = '') -> list[str]:
    """The ROS parameter names :func:`declare_from_dataclass` declares for ``params``: one per
    field, ``field.sub`` for a nested dataclass, none for a field whose default is None."""
    names = []
    for field in dataclasses.fields(params):
        default = getattr(params, field.name)
        if dataclasses.is_dataclass(default):
            names += dataclass_parameter_names(default, prefix=f'{prefix}{field.name}.')
        elif default is not None:
            names.append(f'{prefix}{field.name}')
    return names


def dataclass_from_values(params: Any, values: dict[str, Any], *, prefix: str = '') -> Any:
    """``params`` with the fields named in ``values`` (ROS parameter name -> value, as
    :func:`dataclass_parameter_names` names them) replaced; the dataclass validates them.

    Raises:
        ValueError: a value the dataclass rejects (its message says how to fix it).
    """
    changes = {}
    for field in dataclasses.fields(params):
        default = getattr(params, field.name)
        name = f'{prefix}{field.name}'
        if dataclasses.is_dataclass(default):
            changes[field.name] = dataclass_from_values(default, values, prefix=f'{name}.')
        elif name in values:
            changes[field.name] = parameter_value(default, values[name])
    return dataclasses.replace(params, **changes)


def declare_from_dataclass(node: Node, params: Any, *, prefix: str = '',
                           descriptions: dict[str, str] | None = None,
                           ranges: dict[str, tuple[float, float]] | None = None,
                           read_only: Collection[str] = (), how_it_applies: str = ''
                           ) -> dict[str, Any]:
    """Declare one ROS parameter per field of a frozen ``*Params`` dataclass instance.

    Field docs come from ``descriptions`` (field name -> text), then from the dataclass
    docstring's ``Attributes:`` section. Nested dataclass fields become ``field.sub`` parameters.
    The parameters named in ``read_only`` (full names) are declared read-only (``ros2 param
    set`` refuses them) and their descriptions say so; the others' end with ``how_it_applies``.
    Returns the declared values (after overrides from YAML / command line) as a dict of field
    name -> value, ready for ``dataclasses.replace(params, **values)``.
    """
    descriptions = {**attribute_docs(type(params)), **(descriptions or {})}
    ranges = ranges or {}
    values = {}
    for field in dataclasses.fields(params):
        default = getattr(params, field.name)
        name = f'{prefix}{field.name}'
        if dataclasses.is_dataclass(default):
            nested = declare_from_dataclass(node, default, prefix=f'{name}.',
                                            read_only=read_only, how_it_applies=how_it_applies)
            values[field.name] = dataclasses.replace(default, **nested)
            continue
        if default is None:
            continue  # no type to declare; the dataclass default stays
        if isinstance(default, tuple):
            default = list(default)
        text = descriptions.get(field.name, f'{type(params).__name__}.{field.name}')
        descriptor = ParameterDescriptor(
            description=f'{text} {READ_ONLY_NOTE if name in read_only else how_it_applies}'
            .strip(), read_only=name in read_only)
        if field.name in ranges:
            low, high = ranges[field.name]
            if isinstance(default, int) and not isinstance(default, bool):
                descriptor.integer_range = [IntegerRange(from_value=int(low), to_value=int(high),
                                                         step=0)]
            elif isinstance(default, float):
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=float(low), to_value=float(high), step=0.0)]
        value = declare_parameter(node, name, default, descriptor)
        values[field.name] = parameter_value(getattr(params, field.name), value)
    return values


def format_message(msg: Any, *, max_array: int = 16, indent: int = 0) -> str:
    """A YAML-like multi-line rendering of an rclpy message; long arrays are summarised."""
    lines = []
    pad = '  ' * indent
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        if hasattr(value, 'get_fields_and_field_types'):
            lines.append(f'{pad}{name}:')
            lines.append(format_message(value, max_array=max_array, indent=indent + 1))
            continue
        if hasattr(value, '__len__') and not isinstance(value, str):
            if len(value) > max_array:
                lines.append(f'{pad}{name}: <{len(value)} elements>')
                continue
            items = [v if not hasattr(v, 'get_fields_and_field_types') else
                     '{' + format_message(v, max_array=max_array).replace('\n', ', ') + '}'
                     for v in value]
            lines.append(f'{pad}{name}: [{", ".join(str(v) for v in items)}]')
            continue
        lines.append(f'{pad}{name}: {value!r}' if isinstance(value, str) else
                     f'{pad}{name}: {value}')
    return '\n'.join(lines)


BLAS_THREAD_VARIABLES = ('OPENBLAS_NUM_THREADS', 'OMP_NUM_THREADS', 'MKL_NUM_THREADS')


def limit_blas_threads() -> int | None:
    """Run this process's BLAS on one thread, unless the user set a thread count.

    The stages already run in parallel, one process each, on a few cores. OpenBLAS's worker
    threads spin while they wait for work, so a node that multiplies a few mid-sized matrices
    per frame (the classifier's feature map) kept most of a core busy and slowed the other
    stages: graph p95 159.5 against 120.8 ms in paired 60 s runs, classifier 65 against 21 %
    of a core (README). The environment variables also reach worker processes started later.

    Returns:
        The thread limit applied, or None when one of ``BLAS_THREAD_VARIABLES`` was set.
    """
    import os

    if any(name in os.environ for name in BLAS_THREAD_VARIABLES):
        return None
    os.environ['OPENBLAS_NUM_THREADS'] = os.environ['OMP_NUM_THREADS'] = '1'
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api='blas')
    return 1


def ignore_interrupts_while_stopping() -> None:
    """Ignore SIGINT from now on (call from the main thread when the clean-up starts).

    Ctrl-C in a terminal reaches every process of ``ros2 launch``'s process group, and launch
    then sends each node SIGINT again: that second one would abort the clean-up with a
    KeyboardInterrupt traceback and a non-zero exit. SIGTERM still stops a stuck clean-up.
    """
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_node(node_class: type, args: list[str] | None = None) -> None:
    """``main()`` of every node: init, spin until Ctrl-C or shutdown, clean up (Jazzy style).

    BLAS runs on one thread per node process (:func:`limit_blas_threads`). A
    :class:`~tlessbot_ros.errors.TlessbotError` while constructing the node (a missing model
    file, a bad parameter file) prints one line and exits with code 1. Ctrl-C or SIGTERM, also
    while the node is being constructed, ends it in order with exit code 0: the node is
    destroyed (its ``destroy_node`` joins its threads, which finish the frame in hand) while
    the ROS context is still valid, and only then is the context shut down.
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
