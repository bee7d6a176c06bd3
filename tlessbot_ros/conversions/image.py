"""sensor_msgs/Image <-> numpy arrays.

Supported encodings (sensor_msgs/image_encodings.hpp): rgb8, bgr8, rgba8, bgra8, mono8, mono16,
8UC1, 16UC1 (depth in millimetres, 0 = invalid, realsense-ros) and 32FC1 (depth in metres,
NaN = invalid, REP-118). Row padding in ``step`` and ``is_bigendian`` are honoured.
"""
from __future__ import annotations

from typing import Any, cast

import numpy as np
from numba import njit

from tlessbot_ros.conversions.messages import (
    MessageFactory,
    default_factory,
    make_header,
    message_bytes,
)

# encoding -> (numpy base dtype, channels)
ENCODINGS: dict[str, tuple[np.dtype, int]] = {
    'rgb8': (np.dtype(np.uint8), 3),
    'bgr8': (np.dtype(np.uint8), 3),
    'rgba8': (np.dtype(np.uint8), 4),
    'bgra8': (np.dtype(np.uint8), 4),
    'mono8': (np.dtype(np.uint8), 1),
    '8UC1': (np.dtype(np.uint8), 1),
    'mono16': (np.dtype(np.uint16), 1),
    '16UC1': (np.dtype(np.uint16), 1),
    '16UC2': (np.dtype(np.uint16), 2),   # 16UC2..4: class candidates (core/common/labels.py)
    '16UC3': (np.dtype(np.uint16), 3),
    '16UC4': (np.dtype(np.uint16), 4),
    '32FC1': (np.dtype(np.float32), 1),
}


def _check_encoding(encoding: str) -> tuple[np.dtype, int]:
    try:
        return ENCODINGS[encoding]
    except KeyError:
        raise ValueError(
            f'unsupported image encoding {encoding!r}; expected one of {sorted(ENCODINGS)}'
        ) from None


def image_to_array(msg: Any, *, copy: bool = False) -> np.ndarray:
    """Decode a sensor_msgs/Image.

    Returns:
        (H, W, C) for multi-channel encodings, (H, W) for single-channel ones, in the encoding's
        own channel order and dtype (uint8, uint16 or float32) and native byte order. The array
        is a read-only view of the message buffer unless ``copy`` is True.

    Raises:
        ValueError: unknown encoding, zero size, ``step`` too small, or a data length that does
            not equal ``height * step``.
    """
    dtype, channels = _check_encoding(msg.encoding)
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    if height == 0 or width == 0:
        raise ValueError(f'image has zero size ({width}x{height})')
    row_bytes = width * channels * dtype.itemsize
    if step < row_bytes:
        raise ValueError(f'step {step} is smaller than width*channels*bytes = {row_bytes}')
    buffer = message_bytes(msg.data)
    if buffer.size != height * step:
        raise ValueError(
            f'image data has {buffer.size} bytes, expected height*step = {height}*{step}'
            f' = {height * step}'
        )
    typed = dtype.newbyteorder('>' if msg.is_bigendian else '<')
    # Drop the row padding, then reinterpret the bytes; a view unless a copy is unavoidable.
    rows = buffer.reshape(height, step)[:, :row_bytes]
    array = rows.view(typed).reshape(height, width, channels)
    if not typed.isnative:
        array = array.astype(dtype)
    if channels == 1:
        array = array[:, :, 0]
    return cast(np.ndarray, array.copy() if copy else array)


def array_to_image(
    array: np.ndarray,
    encoding: str,
    *,
    frame_id: str = '',
    stamp_ns: int = 0,
    factory: MessageFactory | None = None,
) -> Any:
    """Encode an array as a sensor_msgs/Image (little-endian, no row padding).

    Args:
        array: (H, W) or (H, W, C) array whose dtype and channel count match ``encoding``.
        encoding: one of :data:`ENCODINGS`.
        frame_id, stamp_ns: header contents.
        factory: message implementation (rclpy by default).
    """
    data = little_endian_pixels(array, encoding)
    height, width, channels = data.shape
    factory = factory or default_factory()
    return factory.new(
        'sensor_msgs/msg/Image',
        header=make_header(frame_id, stamp_ns, factory),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=width * channels * data.itemsize,
        data=factory.uint8_array(data),
    )


def little_endian_pixels(array: np.ndarray, encoding: str) -> np.ndarray:
    """The (H, W, C) C-contiguous little-endian pixels of an image array, checked against
    ``encoding`` (channel count, dtype, non-zero size); what an Image message carries."""
    dtype, channels = _check_encoding(encoding)
    array = np.asarray(array)
    if array.ndim == 2:
        array = array[:, :, None]
    if array.ndim != 3 or array.shape[2] != channels:
        raise ValueError(
            f'encoding {encoding} needs {channels} channel(s), got shape {array.shape}')
    if array.dtype != dtype:
        raise ValueError(f'encoding {encoding} needs dtype {dtype}, got {array.dtype}')
    if array.shape[0] == 0 or array.shape[1] == 0:
        raise ValueError(f'image has zero size ({array.shape[1]}x{array.shape[0]})')
    return np.ascontiguousarray(array, dtype=dtype.newbyteorder('<'))


def image_to_rgb(msg: Any) -> np.ndarray:
    """Colour image as (H, W, 3) uint8 RGB, from rgb8, bgr8, rgba8, bgra8 or mono8."""
    array = image_to_array(msg)
    encoding = msg.encoding
    if encoding == 'rgb8':
        return array
    if encoding == 'bgr8':
        return np.ascontiguousarray(array[:, :, ::-1])
    if encoding == 'rgba8':
        return np.ascontiguousarray(array[:, :, :3])
    if encoding == 'bgra8':
        return np.ascontiguousarray(array[:, :, 2::-1])
    if encoding in ('mono8', '8UC1'):
        return np.repeat(array[:, :, None], 3, axis=2)
    raise ValueError(f'colour images must be rgb8, bgr8, rgba8, bgra8 or mono8, got {encoding!r}')


@njit(cache=True, nogil=True)
def _mm_to_metres(depth_mm: np.ndarray) -> np.ndarray:
    """(H, W) uint16 millimetres -> (H, W) float32 metres ``float32(v) * float32(0.001)``, NaN
    for 0, in one pass (numba multiplies float32 by float32 in float32, as numpy does; a
    65536-entry look-up table through ``np.take`` gives the same bits but first widens the
    indices to an int64 copy of the frame: docs/bench/code-figures.md)."""
    height, width = depth_mm.shape
    out = np.empty((height, width), np.float32)
    scale = np.float32(0.001)
    invalid = np.float32(np.nan)
    for row in range(height):
        for col in range(width):
            v = depth_mm[row, col]
            out[row, col] = np.float32(v) * scale if v else invalid
    return out


def depth_image_to_metres(msg: Any) -> np.ndarray:
    """Depth image (16UC1/mono16 in mm, or 32FC1 in m) as (H, W) float32 metres, NaN = invalid."""
    if msg.encoding in ('16UC1', 'mono16'):
        return _mm_to_metres(image_to_array(msg))
    if msg.encoding == '32FC1':
        depth = image_to_array(msg, copy=True).astype(np.float32, copy=False)
        depth[~np.isfinite(depth) | (depth <= 0)] = np.nan
        return depth
    raise ValueError(f'depth images must be 16UC1, mono16 or 32FC1, got {msg.encoding!r}')


def metres_to_depth_mm(depth_m: np.ndarray) -> np.ndarray:
    """(H, W) float metres (NaN/<=0 invalid) to uint16 millimetres with 0 = invalid, rounded."""
    depth_m = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(depth_m) & (depth_m > 0)
    depth_mm = np.zeros(depth_m.shape, dtype=np.uint16)
    depth_mm[valid] = np.clip(np.rint(depth_m[valid] * 1000.0), 0, 65535).astype(np.uint16)
    return depth_mm
