"""The rclpy helpers of the nodes and the ROS-facing tools, by the import path they have always
had. Each lives in the module of its concern:

- :mod:`~tlessbot_ros.nodes.qos`: ``SENSOR_QOS``, ``RESULT_QOS``.
- :mod:`~tlessbot_ros.nodes.process_setup`: :func:`init_ros` (the package's Fast DDS profile,
  glibc's allocator, ``rclpy.init``), :func:`limit_blas_threads`.
- :mod:`~tlessbot_ros.nodes.signals`: Ctrl-C and SIGTERM (:func:`interrupt_on_signals`,
  :func:`raise_if_interrupted`, :func:`interrupts_deferred`, the unraisable hook).
- :mod:`~tlessbot_ros.nodes.spin`: executors, the spin loop, :func:`run_node`.
- :mod:`~tlessbot_ros.nodes.parameter_fields`: ROS parameters from a ``*Params`` dataclass.
- ``message_class`` and ``format_message``: :mod:`tlessbot_ros.conversions.messages`.

The signal state (``_SIGNALS_RECEIVED``, ``_DEFERRING``, ``_DEFAULT_UNRAISABLEHOOK``) is
:mod:`~tlessbot_ros.nodes.signals`' own: read or set here, it is read or set there.
"""
from __future__ import annotations

import sys
import types

from tlessbot_ros.conversions.messages import format_message, message_class
from tlessbot_ros.nodes import signals
from tlessbot_ros.nodes.parameter_fields import (
    READ_ONLY_NOTE,
    attribute_docs,
    dataclass_from_values,
    dataclass_parameter_names,
    declare_from_dataclass,
    declare_parameter,
    parameter_value,
)
from tlessbot_ros.nodes.process_setup import (
    BLAS_THREAD_VARIABLES,
    DDS_PROFILE_VARIABLES,
    MALLOC_VARIABLES,
    init_ros,
    keep_freed_buffers,
    limit_blas_threads,
    use_package_dds_profile,
)
from tlessbot_ros.nodes.qos import RESULT_QOS, SENSOR_QOS
from tlessbot_ros.nodes.signals import (
    ignore_interrupts_while_stopping,
    interrupt_on_signals,
    interrupts_deferred,
    quiet_half_built_futures,
    raise_if_interrupted,
    spin_once_or_interrupt,
)
from tlessbot_ros.nodes.spin import (
    SIGNAL_POLL_S,
    make_executor,
    run_node,
    spin_until_interrupted,
)

__all__ = [
    'BLAS_THREAD_VARIABLES', 'DDS_PROFILE_VARIABLES', 'MALLOC_VARIABLES', 'READ_ONLY_NOTE',
    'RESULT_QOS', 'SENSOR_QOS', 'SIGNAL_POLL_S', 'attribute_docs', 'dataclass_from_values',
    'dataclass_parameter_names', 'declare_from_dataclass', 'declare_parameter',
    'format_message', 'ignore_interrupts_while_stopping', 'init_ros', 'interrupt_on_signals',
    'interrupts_deferred', 'keep_freed_buffers', 'limit_blas_threads', 'make_executor',
    'message_class', 'parameter_value', 'quiet_half_built_futures', 'raise_if_interrupted',
    'run_node', 'spin_once_or_interrupt', 'spin_until_interrupted', 'use_package_dds_profile']


def _forwarded(name: str) -> property:
    """An attribute of this module that is :mod:`~tlessbot_ros.nodes.signals`' ``name``."""
    return property(lambda module: getattr(signals, name),
                    lambda module, value: setattr(signals, name, value))


class _Module(types.ModuleType):
    """This module, with the signal state read from and set in :mod:`~.signals`."""

    _SIGNALS_RECEIVED = _forwarded('_SIGNALS_RECEIVED')
    _DEFERRING = _forwarded('_DEFERRING')
    _DEFAULT_UNRAISABLEHOOK = _forwarded('_DEFAULT_UNRAISABLEHOOK')


sys.modules[__name__].__class__ = _Module
