"""Parameters that change while a node runs (``ros2 param set``), and those that cannot.

A node declares its parameters through one :class:`LiveParameters`. Each live parameter
belongs to a *group* whose values make one settings object together: a core ``*Params``
dataclass (:meth:`LiveParameters.dataclass`), or whatever a ``build`` function makes of a few
values (a camera pose from its position, target and up vector; a model from its path). On
``ros2 param set`` the group's candidate object is built from its current values and the
new ones, so the dataclass (or ``build``) validates the change exactly as at start-up: a value
it rejects is refused with its message (``Setting parameter failed: <reason>``) and the old
value stays. An accepted change is logged (one info line), counted for ``/diagnostics`` and
applied:

- ``FRAME`` (most): between frames, by the stage's frame thread, which calls
  :meth:`LiveParameters.apply_pending` before each frame, so a frame never sees half of a
  change;
- ``AT_ONCE``: in the parameter callback itself (executor thread): settings that the
  executor's callbacks read (``sync.*``) or that a capture loop reads once per frame;
- with ``warm`` (a model file): built (loaded) in the callback, so a file that cannot be read
  is refused, then warmed up on a background thread, then applied between frames like
  ``FRAME``.

Parameters that cannot change while the node runs (what it subscribes, its processes' files)
are declared read-only (:meth:`LiveParameters.read_only`): rclpy refuses ``ros2 param set``
for them ("Trying to set a read-only parameter"), and ``ros2 param describe`` shows it. Every
description ends with how a change applies, or ``(read-only: ...)``.

rclpy checks the type of a set value against the declared one before any of this (a double
parameter refuses ``2``; write ``2.0``), as at start-up.
"""
from __future__ import annotations

import threading
import traceback
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.nodes.common import (
    READ_ONLY_NOTE,
    dataclass_from_values,
    dataclass_parameter_names,
    declare_from_dataclass,
    declare_parameter,
    parameter_value,
)
from tlessbot_ros.nodes.exit_wait import wait_at_exit

FRAME, AT_ONCE = 'frame', 'at once'
HOW_IT_APPLIES = {FRAME: '(live: a change applies from the next frame)',
                  AT_ONCE: '(live: a change applies at once)'}
WARM_NOTE = ('(live: a new file is loaded at once, or refused if it cannot be; it is used from '
             'the first frame after its warm-up)')
# What a build may raise for a value it refuses (anything else is a bug and propagates).
REFUSALS = (ValueError, TypeError, OSError, TlessbotError)


@dataclass(eq=False)
class _Group:
    """Live parameters that make one settings object (see the module docstring)."""

    values: dict[str, Any]                 # the accepted value of every parameter of the group
    build: Callable[[dict[str, Any]], Any]
    apply: Callable[[Any], None]
    when: str = FRAME
    warm: Callable[[Any], None] | None = None
    generation: int = 0                    # the latest accepted change (warm-ups still running)
    live: tuple[str, ...] = field(default=())


class LiveParameters:
    """The live and read-only parameters of one node (see the module docstring).

    Example:
        >>> parameters = LiveParameters(node)
        >>> node.fusion = parameters.dataclass(FusionParams(), prefix='fusion.',
        ...                                    apply=lambda p: setattr(node, 'fusion', p))
        >>> qos = parameters.read_only('input_qos', 'sensor_data', 'QoS of the subscriptions')
        >>> parameters.apply_pending()   # frame thread, before each frame
    """

    def __init__(self, node: Node) -> None:
        self.node = node
        self.changes = 0           # accepted changes (for /diagnostics)
        self.last_change = ''      # 'name=value, ...' of the latest
        self._owners: dict[str, _Group] = {}
        self._pending: dict[_Group, Any] = {}
        self._lock = threading.Lock()
        # Called for declarations too: a name is owned only once it is declared, so those pass.
        node.add_on_set_parameters_callback(self._on_set)

    # ------------------------------------------------------------------------ declaring
    def read_only(self, name: str, default: Any, description: str) -> Any:
        """Declare ``name`` read-only; its value (after YAML / command-line overrides)."""
        return declare_parameter(self.node, name, default, ParameterDescriptor(
            description=f'{description} {READ_ONLY_NOTE}', read_only=True))

    def dataclass(self, defaults: Any, *, apply: Callable[[Any], None], prefix: str = '',
                  when: str = FRAME, read_only: Collection[str] = (),
                  descriptions: dict[str, str] | None = None,
                  ranges: dict[str, tuple[float, float]] | None = None) -> Any:
        """Declare the fields of a frozen ``*Params`` dataclass as ``<prefix><field>``
        (:func:`~tlessbot_ros.nodes.common.declare_from_dataclass`; the fields named in
        ``read_only``, without prefix, read-only) and return the validated instance; accepted
        changes reach ``apply`` as a new validated instance.

        Raises:
            TlessbotError: a start-up value the dataclass rejects (its message says how to
                fix it), so the node stops with one line (:func:`~.common.run_node`).
        """
        fixed = {f'{prefix}{name}' for name in read_only}
        declare_from_dataclass(self.node, defaults, prefix=prefix, descriptions=descriptions,
                               ranges=ranges, read_only=fixed, how_it_applies=HOW_IT_APPLIES[when])
        names = dataclass_parameter_names(defaults, prefix=prefix)
        values = {name: self.node.get_parameter(name).value for name in names}

        def build(values: dict[str, Any]) -> Any:
            return dataclass_from_values(defaults, values, prefix=prefix)

        try:
            current = build(values)
        except ValueError as error:
            raise TlessbotError(f'{self.node.get_name()}: parameter {prefix}{error}') from None
        self._own(_Group(values, build, apply, when), [n for n in names if n not in fixed])
        return current

    def group(self, declarations: dict[str, tuple[Any, str]], *,
              build: Callable[[dict[str, Any]], Any], apply: Callable[[Any], None],
              when: str = FRAME, warm: Callable[[Any], None] | None = None,
              on_start_error: Callable[[Exception], Any] | None = None) -> Any:
        """Declare ``{name: (default, description)}`` as one live group and return
        ``build(values)``; accepted changes reach ``apply`` as ``build(new values)``, after
        ``warm(it)`` on a background thread when ``warm`` is given. ``build`` refuses a value
        by raising one of :data:`REFUSALS`.

        Raises:
            TlessbotError: a start-up value ``build`` refuses, unless ``on_start_error`` takes
                the error (and returns what to use instead).
        """
        note = WARM_NOTE if warm is not None else HOW_IT_APPLIES[when]
        values = {name: declare_parameter(self.node, name, default, ParameterDescriptor(
            description=f'{description} {note}'))
            for name, (default, description) in declarations.items()}
        group = _Group(values, build, apply, when, warm)
        try:
            current = build(values)
        except REFUSALS as error:
            if on_start_error is not None:
                current = on_start_error(error)
            elif isinstance(error, TlessbotError):
                raise
            else:
                raise TlessbotError(f'{self.node.get_name()}: parameter '
                                    f'{_reason(values, error)}') from None
        self._own(group, list(declarations))
        return current

    def _own(self, group: _Group, names: list[str]) -> None:
        group.live = tuple(names)
        for name in names:
            self._owners[name] = group

    def is_live(self, name: str) -> bool:
        return name in self._owners

    # ------------------------------------------------------------------------ changing
    def _on_set(self, parameters: list[Any]) -> SetParametersResult:
        """rclpy's on-set callback: validate every owned parameter of the set (all or none
        are accepted), then apply or schedule each changed group."""
        changed: dict[_Group, dict[str, Any]] = {}
        for parameter in parameters:
            group = self._owners.get(parameter.name)
            if group is not None:
                changed.setdefault(group, {})[parameter.name] = parameter_value(
                    group.values[parameter.name], parameter.value)
        accepted = []
        for group, new in changed.items():
            values = {**group.values, **new}
            try:
                candidate = group.build(values)
            except REFUSALS as error:
                return SetParametersResult(successful=False, reason=_reason(new, error))
            accepted.append((group, values, candidate, new))
        for group, values, candidate, new in accepted:
            try:
                self._schedule(group, candidate)
            except REFUSALS as error:   # an AT_ONCE apply that fails keeps the old settings
                return SetParametersResult(successful=False, reason=_reason(new, error))
            old = {name: group.values[name] for name in new}
            group.values = values
            self._report(old, new, group)
        return SetParametersResult(successful=True)

    def _schedule(self, group: _Group, candidate: Any) -> None:
        if group.when == AT_ONCE and group.warm is None:
            group.apply(candidate)
            return
        group.generation += 1
        if group.warm is not None:
            thread = threading.Thread(target=self._warm_then_queue,
                                      args=(group, candidate, group.generation), daemon=True,
                                      name=f'{self.node.get_name()}_parameter_warm_up')
            thread.start()
            wait_at_exit(thread)
        else:
            with self._lock:
                self._pending[group] = candidate

    def _warm_then_queue(self, group: _Group, candidate: Any, generation: int) -> None:
        try:
            group.warm(candidate)
        except Exception as error:  # reported; the settings in use stay
            self.node.get_logger().error(f'parameter change not applied: warm-up failed: '
                                         f'{type(error).__name__}: {error}')
            return
        with self._lock:
            if generation == group.generation:   # a later change supersedes this one
                self._pending[group] = candidate

    def _report(self, old: dict[str, Any], new: dict[str, Any], group: _Group) -> None:
        self.changes += 1
        self.last_change = ', '.join(f'{name}={_show(value)}' for name, value in new.items())
        when = ('after its warm-up' if group.warm is not None else
                'now' if group.when == AT_ONCE else 'from the next frame')
        self.node.get_logger().info('parameter ' + ', '.join(
            f'{name}: {_show(old[name])} -> {_show(value)}' for name, value in new.items())
            + f' (applies {when})')

    def apply_pending(self) -> None:
        """Apply the accepted changes waiting for a frame boundary (frame thread only). A
        failing apply is logged; the node keeps running."""
        with self._lock:
            pending, self._pending = self._pending, {}
        for group, candidate in pending.items():
            try:
                group.apply(candidate)
            except Exception as error:  # never take the frame thread down
                self.node.get_logger().error(f'applying a parameter change failed: '
                                             f'{type(error).__name__}: {error}')
                self.node.get_logger().debug(traceback.format_exc())

    @property
    def pending(self) -> bool:
        """Whether accepted changes wait for the next frame."""
        with self._lock:
            return bool(self._pending)


def _reason(new: dict[str, Any], error: Exception) -> str:
    """The refusal's reason: the validator's message, naming the parameter if it does not."""
    message = str(error)
    names = [name for name in new if name not in message]
    return f'{", ".join(names)}: {message}' if names else message


def _show(value: Any) -> str:
    return repr(value) if isinstance(value, str) else str(
        list(value) if isinstance(value, (tuple, list)) or hasattr(value, 'typecode') else value)
