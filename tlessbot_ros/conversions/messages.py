"""Building messages without binding to one message implementation.

A :class:`MessageFactory` makes a message from its ROS type name ('sensor_msgs/msg/Image') and
keyword fields. :class:`RclpyFactory` makes rclpy messages (imported on first use);
:class:`RosbagsFactory` makes rosbags dataclasses from a typestore, for writing bags without ROS.
"""
from __future__ import annotations

import array
import importlib
from typing import Any, Protocol

import numpy as np

NS_PER_S = 1_000_000_000


class MessageFactory(Protocol):
    """Makes messages of one implementation (rclpy or rosbags)."""

    def new(self, msgtype: str, **fields: Any) -> Any:
        """Message of ROS type ``msgtype`` ('pkg/msg/Name') with the given fields."""
        ...

    def uint8_array(self, data: bytes | np.ndarray) -> Any:
        """The value to store in a ``uint8[]`` field."""
        ...

    def float64_array(self, values: np.ndarray) -> Any:
        """The value to store in a fixed-size ``float64[N]`` field (K, R, P) or ``float64[]``."""
        ...


_CLASSES: dict[str, type] = {}


def message_class(type_name: str) -> type:
    """rclpy message class of 'pkg/msg/Name' (also accepts 'pkg/Name'; cached).

    Raises:
        ValueError: a malformed name, or a type this environment does not have.
    """
    cached = _CLASSES.get(type_name)
    if cached is not None:
        return cached
    parts = type_name.split('/')
    if len(parts) == 2:
        parts = [parts[0], 'msg', parts[1]]
    if len(parts) != 3:
        raise ValueError(f"message type must look like 'pkg/msg/Name', got {type_name!r}")
    package, kind, name = parts
    try:
        cls: type = getattr(importlib.import_module(f'{package}.{kind}'), name)
    except (ImportError, AttributeError):
        raise ValueError(f'message type {type_name!r} is not available in this environment') \
            from None
    _CLASSES[type_name] = cls
    return cls


class RclpyFactory:
    """Factory for rclpy (rosidl_generator_py) messages. Unset fields keep their defaults."""

    def new(self, msgtype: str, **fields: Any) -> Any:
        return message_class(msgtype)(**fields)

    def uint8_array(self, data: bytes | np.ndarray) -> Any:
        # array.array('B') is stored without per-element checks by rclpy's setters. frombytes
        # copies in one go; array.array('B', memoryview) iterates per byte (36 ms for a
        # 640x480 rgb8 image, measured).
        values = array.array('B')
        values.frombytes(_as_bytes(data))
        return values

    def float64_array(self, values: np.ndarray) -> Any:
        return np.asarray(values, dtype=np.float64).ravel()


class RosbagsFactory:
    """Factory for rosbags message dataclasses (every field is required by their constructors,
    so missing fields are filled with zero values of the right type)."""

    def __init__(self, typestore: Any | None = None) -> None:
        if typestore is None:
            from rosbags.typesys import Stores, get_typestore

            typestore = get_typestore(Stores.ROS2_JAZZY)
        self.typestore = typestore

    def new(self, msgtype: str, **fields: Any) -> Any:
        cls = self.typestore.types[msgtype]
        _, fieldlist = self.typestore.fielddefs[msgtype]
        for name, desc in fieldlist:
            if name not in fields:
                fields[name] = self._zero_of(desc)
        return cls(**fields)

    def _zero_of(self, desc: Any) -> Any:
        kind = desc[0].name if hasattr(desc[0], 'name') else str(desc[0])
        if kind == 'NAME':
            return self.new(desc[1])
        if kind == 'BASE':
            base = desc[1][0]
            if base == 'string':
                return ''
            if base == 'bool':
                return False
            return 0.0 if base.startswith('float') else 0
        if kind == 'ARRAY':  # fixed size
            sub, size = desc[1]
            if sub[0].name == 'BASE' and sub[1][0] != 'string':
                return np.zeros(size, dtype=_np_dtype(sub[1][0]))
            return [self._zero_of(sub) for _ in range(size)]
        # SEQUENCE: variable length
        sub = desc[1][0]
        if sub[0].name == 'BASE' and sub[1][0] != 'string':
            return np.zeros(0, dtype=_np_dtype(sub[1][0]))
        return []

    def uint8_array(self, data: bytes | np.ndarray) -> Any:
        return np.frombuffer(_as_bytes(data), dtype=np.uint8)

    def float64_array(self, values: np.ndarray) -> Any:
        return np.asarray(values, dtype=np.float64).ravel()


def _as_bytes(data: bytes | np.ndarray) -> bytes | memoryview:
    if isinstance(data, bytes):
        return data
    return np.ascontiguousarray(data).reshape(-1).view(np.uint8).data


def _np_dtype(base: str) -> Any:
    return {'bool': np.bool_, 'byte': np.uint8, 'char': np.uint8, 'octet': np.uint8,
            'float32': np.float32, 'float64': np.float64, 'int8': np.int8, 'uint8': np.uint8,
            'int16': np.int16, 'uint16': np.uint16, 'int32': np.int32, 'uint32': np.uint32,
            'int64': np.int64, 'uint64': np.uint64}[base]


_default_factory: RclpyFactory | None = None


def default_factory() -> MessageFactory:
    """The shared :class:`RclpyFactory` (rclpy is imported only when a message is made)."""
    global _default_factory
    if _default_factory is None:
        _default_factory = RclpyFactory()
    return _default_factory


def stamp_to_ns(stamp: Any) -> int:
    """builtin_interfaces/Time (sec, nanosec) to integer nanoseconds."""
    return int(stamp.sec) * NS_PER_S + int(stamp.nanosec)


def ns_to_stamp(stamp_ns: int, factory: MessageFactory | None = None) -> Any:
    """Integer nanoseconds to a builtin_interfaces/Time message."""
    if stamp_ns < 0:
        raise ValueError(f'stamps must be non-negative, got {stamp_ns} ns')
    factory = factory or default_factory()
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return factory.new('builtin_interfaces/msg/Time', sec=sec, nanosec=nanosec)


def make_header(frame_id: str, stamp_ns: int, factory: MessageFactory | None = None) -> Any:
    """std_msgs/Header with the given frame and stamp."""
    factory = factory or default_factory()
    return factory.new('std_msgs/msg/Header', stamp=ns_to_stamp(stamp_ns, factory),
                       frame_id=frame_id)


def message_bytes(data: Any) -> np.ndarray:
    """A ``uint8[]`` field (array.array, numpy array, bytes or list) as a 1-D uint8 view."""
    if isinstance(data, (list, tuple)):
        return np.asarray(data, dtype=np.uint8)
    if isinstance(data, np.ndarray):
        return data.reshape(-1).view(np.uint8)
    return np.frombuffer(data, dtype=np.uint8)


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
