"""ROS 2 CDR bytes read and stamped without message objects.

Layout (OMG CDR, ROS 2 XCDR1 plain encoding): a 4-byte encapsulation header (``00 01``:
little-endian, ``00 00``: big-endian; ``00 03``/``00 02`` the same for parameter lists), then
the fields, each aligned to its size from the end of that header. A string is a uint32 length
counting its terminating NUL, then the bytes and the NUL. A message whose first field is a
std_msgs/Header starts, after the encapsulation, with the Header's int32 sec and uint32
nanosec: :func:`header_stamp_ns` and :func:`restamp_cdr` read and replace those 8 bytes.
"""
from __future__ import annotations

import struct
from typing import cast

from tlessbot_ros.errors import BagError

# encapsulation id -> struct byte order: CDR_BE, CDR_LE, PL_CDR_BE, PL_CDR_LE
ENCAPSULATION = {b'\x00\x00': '>', b'\x00\x01': '<', b'\x00\x02': '>', b'\x00\x03': '<'}
_LITTLE_ENDIAN = (b'\x00\x01', b'\x00\x03')
_HEADER_FIRST: dict[str, bool] = {}


class CdrReader:
    """Reads the fields of a CDR message in order (``offset`` counts from the end of the
    encapsulation header).

    Raises:
        ValueError: not CDR (bad encapsulation header), or a field past the end of the bytes.
    """

    def __init__(self, raw: bytes, *, what: str = 'CDR message') -> None:
        if len(raw) < 4 or bytes(raw[:2]) not in ENCAPSULATION:
            raise ValueError('not a CDR message (bad encapsulation header)')
        self.raw, self.order, self.offset = raw, ENCAPSULATION[bytes(raw[:2])], 0
        self.what = what

    def take(self, size: int, align: int) -> int:
        """Skip the padding to ``align`` and ``size`` bytes; returns their start in ``raw``."""
        self.offset += -self.offset % align
        start = 4 + self.offset
        if start + size > len(self.raw):
            raise ValueError(f'{self.what} is truncated: {len(self.raw)} bytes, a field needs '
                             f'{start + size}')
        self.offset += size
        return start

    def u32(self) -> int:
        return cast(int, struct.unpack_from(self.order + 'I', self.raw, self.take(4, 4))[0])

    def i32(self) -> int:
        return cast(int, struct.unpack_from(self.order + 'i', self.raw, self.take(4, 4))[0])

    def u8(self) -> int:
        return self.raw[self.take(1, 1)]

    def string(self) -> str:
        length = self.u32()
        start = self.take(length, 1)
        text = bytes(self.raw[start:start + length])
        if length == 0 or text[-1:] != b'\x00':
            raise ValueError(f'{self.what} holds a string without its terminating NUL')
        return text[:-1].decode('utf-8', errors='replace')

    def stamp_ns(self) -> int:
        """A builtin_interfaces/Time (int32 sec, uint32 nanosec) in nanoseconds."""
        sec = self.i32()
        return sec * 1_000_000_000 + self.u32()


def starts_with_header(msgtype: str) -> bool:
    """Whether a message type's first field is a std_msgs/Header (cached)."""
    if msgtype not in _HEADER_FIRST:
        from rosbags.typesys import Stores, get_typestore

        fields = get_typestore(Stores.ROS2_JAZZY).fielddefs.get(msgtype, ([], []))[1]
        _HEADER_FIRST[msgtype] = bool(fields) and fields[0][0] == 'header' and \
            fields[0][1][1] == 'std_msgs/msg/Header'
    return _HEADER_FIRST[msgtype]


def restamp_cdr(raw: bytes, stamp_ns: int) -> bytes:
    """A copy of a CDR message whose first field is a Header, with ``header.stamp`` replaced.

    In ROS 2 CDR the 4-byte encapsulation is followed directly by the Header's int32 sec and
    uint32 nanosec, so the stamp is bytes 4..12; nothing else moves.

    Raises:
        BagError: a big-endian message (bags and replays of them are little-endian).
    """
    if raw[:2] not in _LITTLE_ENDIAN:
        raise BagError('only little-endian CDR messages can be restamped')
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return raw[:4] + int(sec).to_bytes(4, 'little', signed=True) + \
        int(nanosec).to_bytes(4, 'little') + raw[12:]


def header_stamp_ns(raw: bytes) -> int:
    """``header.stamp`` of a CDR message whose first field is a Header (the 4-byte
    encapsulation header says the byte order)."""
    if len(raw) < 12:
        raise ValueError(f'a CDR message with a Header has at least 12 bytes, got {len(raw)}')
    return CdrReader(raw).stamp_ns()
