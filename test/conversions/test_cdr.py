"""The CDR header codec: stamps read in either byte order and replaced in place."""
from __future__ import annotations

import pytest

from tlessbot_ros.conversions.cdr import CdrReader, header_stamp_ns, restamp_cdr
from tlessbot_ros.errors import BagError

STAMP = 1_700_000_001_000_000_123


def _header_message(order: str) -> bytes:
    sec, nanosec = divmod(STAMP, 1_000_000_000)
    little = order == 'little'
    return (b'\x00\x01' if little else b'\x00\x00') + b'\x00\x00' + \
        sec.to_bytes(4, order, signed=True) + nanosec.to_bytes(4, order) + \
        (2).to_bytes(4, order) + b'a\x00'


@pytest.mark.parametrize('order', ['little', 'big'])
def test_header_stamp_and_frame_in_either_byte_order(order):
    raw = _header_message(order)
    assert header_stamp_ns(raw) == STAMP
    reader = CdrReader(raw)
    assert reader.stamp_ns() == STAMP and reader.string() == 'a'


def test_restamp_replaces_only_the_stamp_of_little_endian_messages():
    raw = _header_message('little')
    moved = restamp_cdr(raw, 42)
    assert header_stamp_ns(moved) == 42 and moved[12:] == raw[12:] and len(moved) == len(raw)
    with pytest.raises(BagError, match='little-endian'):
        restamp_cdr(_header_message('big'), 42)


def test_short_or_foreign_bytes_are_value_errors():
    with pytest.raises(ValueError, match='at least 12 bytes'):
        header_stamp_ns(b'\x00\x01\x00\x00')
    with pytest.raises(ValueError, match='encapsulation'):
        header_stamp_ns(b'\x07\x07' + bytes(10))
    reader = CdrReader(_header_message('little')[:14], what='Header CDR')
    reader.stamp_ns()
    with pytest.raises(ValueError, match='Header CDR is truncated'):
        reader.string()
