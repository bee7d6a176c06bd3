"""sensor_msgs/Image straight from and to CDR bytes, without rclpy message objects.

Image topics carry megabytes per message. Turning CDR into an rclpy ``Image`` copies the pixels
twice (into C, then into a Python ``array``), and publishing one serialises it again (timed
in docs/design.md, docs/bench/code-figures.md). Here the pixels are copied
once when a message is built, and not at all when one is read: :func:`image_from_cdr` returns
a duck-typed Image whose ``data`` is a read-only view of the received bytes, which every reader
in this package accepts. ``Publisher.publish(bytes)`` sends such bytes as they are.

Layout (OMG CDR, ROS 2 XCDR1 plain encoding, read by :class:`~tlessbot_ros.conversions.cdr.
CdrReader`): a 4-byte encapsulation header (``00 01``: little-endian), then, aligned to each
field's size from the end of that header: Header (int32 sec, uint32 nanosec, string frame_id),
uint32 height, uint32 width, string encoding, uint8 is_bigendian, uint32 step, sequence<uint8>
data. A string is a uint32 length counting its terminating NUL, then the bytes and the NUL.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np

from tlessbot_ros.conversions.cdr import CdrReader
from tlessbot_ros.conversions.image import little_endian_pixels


@dataclass(frozen=True)
class Stamp:
    sec: int
    nanosec: int


@dataclass(frozen=True)
class Header:
    stamp: Stamp
    frame_id: str


@dataclass(frozen=True)
class CdrImage:
    """A sensor_msgs/Image read from CDR; ``data`` is a read-only uint8 view of those bytes."""

    header: Header
    height: int
    width: int
    encoding: str
    is_bigendian: int
    step: int
    data: np.ndarray


def image_from_cdr(raw: bytes) -> CdrImage:
    """Read a serialised sensor_msgs/Image without copying its pixels.

    Raises:
        ValueError: not CDR, or truncated (the pixel checks are :func:`image_to_array`'s).
    """
    reader = CdrReader(raw, what='Image CDR')
    stamp = Stamp(reader.i32(), reader.u32())
    frame_id = reader.string()
    height, width = reader.u32(), reader.u32()
    encoding = reader.string()
    is_bigendian = reader.u8()
    step = reader.u32()
    size = reader.u32()
    start = reader.take(size, 1)
    data = np.frombuffer(raw, np.uint8, count=size, offset=start)
    return CdrImage(Header(stamp, frame_id), height, width, encoding, is_bigendian, step, data)


def image_to_cdr(array: np.ndarray, encoding: str, *, frame_id: str = '',
                 stamp_ns: int = 0) -> bytes:
    """Serialise an array as a little-endian sensor_msgs/Image, as rclpy would (the bytes
    equal ``serialize_message(array_to_image(...))`` up to padding bytes, whose value CDR
    leaves open).

    Args:
        array: (H, W) or (H, W, C) array whose dtype and channel count match ``encoding``.
    """
    pixels = little_endian_pixels(array, encoding)
    height, width, channels = pixels.shape
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    parts: list[bytes | memoryview] = [b'\x00\x01\x00\x00']
    offset = 0

    def put(data: bytes, align: int) -> None:
        nonlocal offset
        pad = -offset % align
        parts.append(b'\x00' * pad + data)
        offset += pad + len(data)

    def put_string(text: str) -> None:
        encoded = text.encode() + b'\x00'
        put(struct.pack('<I', len(encoded)), 4)
        put(encoded, 1)

    put(struct.pack('<iI', sec, nanosec), 4)
    put_string(frame_id)
    put(struct.pack('<II', height, width), 4)
    put_string(encoding)
    put(b'\x00', 1)                                  # is_bigendian
    put(struct.pack('<II', width * channels * pixels.itemsize, pixels.nbytes), 4)
    parts.append(pixels.data.cast('B'))      # joined below: the pixels' only copy
    return b''.join(parts)
