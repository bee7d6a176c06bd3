"""The byte protocol between :class:`~tlessbot_ros.parallel.pose_pool.PoseWorkerPool` and its
workers (no pickle: JSON headers and raw little-endian arrays).

A message is a 4-byte little-endian header length, a UTF-8 JSON header, and, when the header
says ``payload_bytes`` > 0, that many payload bytes. Floats survive the trip exactly (JSON
writes Python's shortest repr of a float64).
"""
from __future__ import annotations

import dataclasses
import json
import struct
from dataclasses import asdict
from typing import Any, BinaryIO

import numpy as np

from tlessbot_ros.core.pose import PoseCandidate

_LENGTH = struct.Struct('<I')
MAX_HEADER_BYTES = 1 << 20


class WireError(RuntimeError):
    """The other end closed the pipe or sent something that is not a message."""


def encode_message(header: dict[str, Any], payload: bytes = b'') -> bytes:
    """One message as bytes."""
    body = json.dumps({**header, 'payload_bytes': len(payload)}, default=_builtin).encode()
    return _LENGTH.pack(len(body)) + body + payload


def write_message(stream: BinaryIO, header: dict[str, Any], payload: bytes = b'') -> None:
    """Write one message and flush."""
    stream.write(encode_message(header, payload))
    stream.flush()


def read_message(stream: BinaryIO) -> tuple[dict[str, Any], bytes]:
    """Read one message: (header, payload). Raises :class:`WireError` at end of stream."""
    length = _read_exactly(stream, _LENGTH.size)
    (size,) = _LENGTH.unpack(length)
    if size > MAX_HEADER_BYTES:
        raise WireError(f'message header of {size} bytes: not this protocol')
    try:
        header = json.loads(_read_exactly(stream, size))
    except ValueError as error:
        raise WireError(f'message header is not JSON: {error}') from error
    if not isinstance(header, dict):
        raise WireError('message header is not a JSON object')
    return header, _read_exactly(stream, int(header.get('payload_bytes', 0)))


def _builtin(value: Any) -> Any:
    """numpy scalars (a float32 fitness, an int64 index) as Python numbers."""
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f'{type(value).__name__} is not JSON serialisable')


def _read_exactly(stream: BinaryIO, size: int) -> bytes:
    data = b''
    while len(data) < size:
        chunk = stream.read(size - len(data))
        if not chunk:
            raise WireError('the other end closed the pipe')
        data += chunk
    return data


def params_to_json(params: Any) -> dict[str, Any]:
    """A frozen ``*Params`` dataclass (nested ones too) as JSON fields."""
    return asdict(params)


def params_from_json(params_class: type, fields: dict[str, Any]) -> Any:
    """Inverse of :func:`params_to_json`: missing fields keep their defaults, nested
    dataclasses and tuples are rebuilt, and the dataclass validates the values.

    Raises:
        WireError: a field ``params_class`` does not have.
    """
    defaults = params_class()
    names = {f.name for f in dataclasses.fields(defaults)}
    unknown = sorted(set(fields) - names)
    if unknown:
        raise WireError(f'{params_class.__name__} has no field(s) {unknown}')
    values = {}
    for name, value in fields.items():
        default = getattr(defaults, name)
        if dataclasses.is_dataclass(default) and isinstance(value, dict):
            value = params_from_json(type(default), value)
        elif isinstance(default, tuple):
            value = tuple(value)
        values[name] = value
    return dataclasses.replace(defaults, **values)


def points_to_bytes(points: np.ndarray) -> bytes:
    """(N, 3) points -> little-endian float64 bytes."""
    return np.ascontiguousarray(points, dtype='<f8').tobytes()


def points_from_bytes(data: bytes) -> np.ndarray:
    """Inverse of :func:`points_to_bytes`: (N, 3) float64."""
    if len(data) % 24:
        raise WireError(f'{len(data)} point bytes are not a whole number of (x, y, z) float64')
    return np.frombuffer(data, dtype='<f8').reshape(-1, 3).astype(np.float64)


def candidate_to_json(candidate: PoseCandidate | None) -> dict[str, Any] | None:
    if candidate is None:
        return None
    return {**asdict(candidate), 'T_camera_object': matrix_to_json(candidate.T_camera_object)}


def candidate_from_json(fields: dict[str, Any] | None) -> PoseCandidate | None:
    if fields is None:
        return None
    return PoseCandidate(**{**fields,
                            'T_camera_object': matrix_from_json(fields['T_camera_object'])})


def matrix_to_json(T: np.ndarray | None) -> list[float] | None:
    return None if T is None else [float(v) for v in np.asarray(T, np.float64).ravel()]


def matrix_from_json(values: list[float] | None, size: int = 4) -> np.ndarray | None:
    return None if values is None else np.asarray(values, np.float64).reshape(size, size)
