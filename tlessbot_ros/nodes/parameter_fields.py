"""ROS parameters from the fields of a core ``*Params`` dataclass, so code and YAML share one
truth (:func:`declare_from_dataclass`; :mod:`tlessbot_ros.nodes.parameters` makes them live)."""
from __future__ import annotations

import dataclasses
from collections.abc import Collection
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

READ_ONLY_NOTE = '(read-only: set it at start-up)'


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
