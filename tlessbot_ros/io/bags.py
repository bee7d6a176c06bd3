"""Reading rosbag2 bags (mcap or sqlite3) with rosbags, with errors a user can act on.

Reads the bags :mod:`tlessbot_ros.io.bag_writer` writes (zstd chunks of plain CDR) and the ones
tlessbot wrote before it, whose every message was its own zstd frame ('message' compression):
a bag folder says so in metadata.yaml and rosbags decompresses; a bare ``.mcap`` of such a bag
does not, so a message that is a zstd frame is decompressed here (CDR never starts like one).
"""
from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tlessbot_ros.errors import BagError
from tlessbot_ros.io.bag_writer import QosOffer

ZSTD_FRAME_MAGIC = b'\x28\xb5\x2f\xfd'   # a CDR message starts with 0x00 (its encapsulation)


def plain_cdr(raw: bytes) -> bytes:
    """A message's CDR bytes, decompressed if they are a zstd frame."""
    if not raw.startswith(ZSTD_FRAME_MAGIC):
        return raw
    import zstandard

    return zstandard.ZstdDecompressor().decompressobj().decompress(raw)


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


def bag_offered_qos(path: str | Path) -> dict[str, list[QosOffer]]:
    """Topic -> the QoS profiles its publishers offered, as the bag recorded them."""
    reader = _open_reader(Path(path))
    try:
        return {c.topic: [_qos_offer(q) for q in getattr(c.ext, 'offered_qos_profiles', ())]
                for c in reader.connections}
    finally:
        reader.close()


def _qos_offer(qos: Any) -> QosOffer:
    """A rosbags ``Qos`` as a :class:`QosOffer`."""
    return QosOffer(qos.history.name.lower(), qos.depth, qos.reliability.name.lower(),
                    qos.durability.name.lower(), tuple(qos.deadline), tuple(qos.lifespan),
                    qos.liveliness.name.lower(), tuple(qos.liveliness_lease_duration),
                    qos.avoid_ros_namespace_conventions)


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
                                 plain_cdr(bytes(raw)))
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

