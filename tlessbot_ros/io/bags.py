"""Reading rosbag2 bags (mcap or sqlite3) with rosbags, with errors a user can act on."""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tlessbot_ros.errors import BagError


@dataclass(frozen=True)
class BagMessage:
    """One raw message: topic, ROS type name, receive time (ns) and its CDR bytes."""

    topic: str
    msgtype: str
    log_time_ns: int
    raw: bytes


def _open_reader(path: Path) -> Any:
    from rosbags.highlevel import AnyReader

    if not path.exists():
        raise BagError(f'bag not found: {path}')
    try:
        reader = AnyReader([path])
        reader.open()
    except Exception as error:  # rosbags raises several unrelated types for bad files
        raise BagError(f'cannot open bag {path}: {error}') from None
    return reader


def bag_topics(path: str | Path) -> dict[str, str]:
    """Topic -> ROS type name of a bag."""
    reader = _open_reader(Path(path))
    try:
        return {c.topic: c.msgtype for c in reader.connections}
    finally:
        reader.close()


def read_bag(path: str | Path, topics: Sequence[str] | None = None) -> Iterator[BagMessage]:
    """Raw messages of ``topics`` (all when None) in log-time order.

    Raises:
        BagError: missing, unreadable, corrupt or truncated bag, or a requested topic that the
            bag does not have.
    """
    path = Path(path)
    reader = _open_reader(path)
    try:
        available = {c.topic for c in reader.connections}
        if topics:
            missing = sorted(set(topics) - available)
            if missing:
                raise BagError(f'bag {path} has no topic(s) {missing}; it has {sorted(available)}')
        connections = [c for c in reader.connections if not topics or c.topic in topics]
        try:
            for connection, log_time_ns, raw in reader.messages(connections=connections):
                yield BagMessage(connection.topic, connection.msgtype, int(log_time_ns),
                                 bytes(raw))
        except BagError:
            raise
        except Exception as error:
            raise BagError(f'bag {path} is corrupt or truncated: {error}') from None
    finally:
        reader.close()


def deserialize(message: BagMessage, typestore: Any | None = None) -> Any:
    """The rosbags dataclass of a raw message (ROS 2 CDR)."""
    if typestore is None:
        from rosbags.typesys import Stores, get_typestore

        typestore = get_typestore(Stores.ROS2_JAZZY)
    try:
        return typestore.deserialize_cdr(message.raw, message.msgtype)
    except Exception as error:
        raise BagError(f'cannot decode a {message.msgtype} on {message.topic}: {error}') from None


_CDR_LITTLE_ENDIAN = (b'\x00\x01', b'\x00\x03')  # CDR_LE, PL_CDR_LE encapsulation ids
_HEADER_FIRST: dict[str, bool] = {}


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
    """
    if raw[:2] not in _CDR_LITTLE_ENDIAN:
        raise BagError('only little-endian CDR messages can be restamped')
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    return raw[:4] + int(sec).to_bytes(4, 'little', signed=True) + \
        int(nanosec).to_bytes(4, 'little') + raw[12:]


def header_stamp_ns(raw: bytes) -> int:
    """``header.stamp`` of a CDR message whose first field is a Header (the 4-byte
    encapsulation header says the byte order: 0x0001 little-endian, 0x0000 big-endian)."""
    if len(raw) < 12:
        raise ValueError(f'a CDR message with a Header has at least 12 bytes, got {len(raw)}')
    order = 'little' if raw[1] & 1 else 'big'
    return int.from_bytes(raw[4:8], order, signed=True) * 1_000_000_000 + \
        int.from_bytes(raw[8:12], order)
