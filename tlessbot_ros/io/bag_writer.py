"""Writing rosbag2 bags as rosbag2 itself (ROS 2 Jazzy, metadata version 9) writes them.

The one bag writer of the package (the simulator's bags, ``tlessbot record``). An mcap bag is
what ``ros2 bag record -s mcap --storage-config-file`` with ``compression: Zstd`` makes, so
Foxglove, ``ros2 bag play``, the ``mcap`` tools and rosbags all read it, with or without its
``metadata.yaml``:

- the file's chunks are zstd-compressed and the messages in them are plain CDR (rosbag2's MCAP
  plugin refuses per-message compression, and readers without ``metadata.yaml`` cannot know of
  it);
- one ``ros2msg`` schema per type with the full concatenated ``.msg`` definitions;
- one ``cdr`` channel per topic whose metadata has ``offered_qos_profiles`` (YAML text) and
  ``topic_type_hash`` (REP-2011 ``RIHS01_...``);
- a ``rosbag2`` metadata record holding ``serialized_metadata``, and ``metadata.yaml`` beside
  the file, both with ``compression_format`` and ``compression_mode`` empty: chunk compression
  is the storage's business, not rosbag2's.

sqlite3 bags are written by rosbags.
"""
from __future__ import annotations

import shutil
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO

import yaml

from tlessbot_ros import __version__
from tlessbot_ros.errors import BagError

METADATA_VERSION = 9
ROS_DISTRO = 'jazzy'   # the typestore's: the message definitions and type hashes are Jazzy's
CHUNK_BYTES = 4 * 1024 * 1024   # rosbag2's 'zstd_small' preset; a chunk holds a few images
STORAGES = ('mcap', 'sqlite3')
RMW_DURATION_INFINITE = (9_223_372_036, 854_775_807)   # (sec, nsec)


@dataclass(frozen=True)
class QosOffer:
    """One QoS profile a publisher offered, as rosbag2 stores it (metadata version 9).

    Policies are spelled as rmw spells them ('keep_last', 'reliable', 'volatile',
    'automatic', 'unknown', ...); durations are (sec, nsec).
    """

    history: str
    depth: int
    reliability: str
    durability: str
    deadline: tuple[int, int]
    lifespan: tuple[int, int]
    liveliness: str
    liveliness_lease_duration: tuple[int, int]
    avoid_ros_namespace_conventions: bool = False

    def as_rosbag2(self) -> dict[str, Any]:
        """The mapping rosbag2 writes, in its key order."""
        def duration(value: tuple[int, int]) -> dict[str, int]:
            return {'sec': value[0], 'nsec': value[1]}

        return {'history': self.history, 'depth': self.depth,
                'reliability': self.reliability, 'durability': self.durability,
                'deadline': duration(self.deadline), 'lifespan': duration(self.lifespan),
                'liveliness': self.liveliness,
                'liveliness_lease_duration': duration(self.liveliness_lease_duration),
                'avoid_ros_namespace_conventions': self.avoid_ros_namespace_conventions}


# What the ROS graph reports for a publisher with the nodes' RESULT_QOS (reliable, volatile,
# keep last 10), which is how `ros2 bag record` would store camera_driver's topics: DDS does
# not carry history, so it reads 'unknown' with depth 0.
RELIABLE_OFFER = QosOffer('unknown', 0, 'reliable', 'volatile', RMW_DURATION_INFINITE,
                          RMW_DURATION_INFINITE, 'automatic', RMW_DURATION_INFINITE)


def offered_qos(profile: Any) -> QosOffer:
    """The :class:`QosOffer` of an rclpy ``QoSProfile`` (duck-typed: policies with
    ``short_key``, durations with ``nanoseconds``), e.g. from
    ``node.get_publishers_info_by_topic(topic)[i].qos_profile``."""
    def duration(value: Any) -> tuple[int, int]:
        sec, nsec = divmod(int(value.nanoseconds), 1_000_000_000)
        return sec, nsec

    return QosOffer(profile.history.short_key, int(profile.depth),
                    profile.reliability.short_key, profile.durability.short_key,
                    duration(profile.deadline), duration(profile.lifespan),
                    profile.liveliness.short_key, duration(profile.liveliness_lease_duration),
                    bool(profile.avoid_ros_namespace_conventions))


class _Rosbag2Dumper(yaml.SafeDumper):
    """Block YAML laid out as rosbag2's yaml-cpp writes it: sequences indented under their key,
    "" for an empty string, ~ for null, no line folding, no anchors."""

    def ignore_aliases(self, data: Any) -> bool:
        return True

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> Any:
        return super().increase_indent(flow, False)


_Rosbag2Dumper.add_representer(str, lambda dumper, value: dumper.represent_scalar(
    'tag:yaml.org,2002:str', value, style='"' if value == '' else None))
_Rosbag2Dumper.add_representer(type(None), lambda dumper, _: dumper.represent_scalar(
    'tag:yaml.org,2002:null', '~'))


def dump_rosbag2_yaml(data: Any) -> str:
    """YAML text of ``data`` as rosbag2 writes it (keys in the given order)."""
    return yaml.dump(data, Dumper=_Rosbag2Dumper, sort_keys=False, default_flow_style=False,
                     width=1 << 16, allow_unicode=True).removesuffix('\n')


@dataclass
class _Topic:
    msgtype: str
    offers: tuple[QosOffer, ...]
    type_hash: str
    handle: Any = None       # the storage's channel or connection
    count: int = 0


@dataclass
class _Span:
    """First and last log time written (ns)."""

    start: int | None = None
    end: int | None = None

    def add(self, t_ns: int) -> None:
        self.start = t_ns if self.start is None else min(self.start, t_ns)
        self.end = t_ns if self.end is None else max(self.end, t_ns)


class BagWriter:
    """A new rosbag2 bag folder; use as a context manager::

        with BagWriter('run1') as bag:
            bag.add_topic('/side/color/image_raw', 'sensor_msgs/msg/Image', [RELIABLE_OFFER])
            bag.write('/side/color/image_raw', log_time_ns, cdr_bytes)

    Args:
        path: the bag folder; must not exist.
        storage: 'mcap' or 'sqlite3'.
        compress: zstd-compress the mcap file's chunks.
        typestore: rosbags typestore giving message definitions and type hashes
            (default: ROS 2 Jazzy).

    Raises:
        BagError: the folder exists, an unknown storage or message type, or a topic written
            before it was added.
    """

    def __init__(self, path: str | Path, *, storage: str = 'mcap', compress: bool = True,
                 typestore: Any | None = None) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f'output bag {self.path} exists; choose a new path')
        if storage not in STORAGES:
            raise BagError(f'unknown bag storage {storage!r}; use one of {STORAGES}')
        if typestore is None:
            from rosbags.typesys import Stores, get_typestore

            typestore = get_typestore(Stores.ROS2_JAZZY)
        self.storage, self.compress, self.typestore = storage, compress, typestore
        self.topics: dict[str, _Topic] = {}
        self._span = _Span()
        self._file: _McapFile | _Sqlite3File | None = None

    def __enter__(self) -> BagWriter:
        self.open()
        return self

    def __exit__(self, exc_type: Any, *_: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def abort(self) -> None:
        """Give the bag up: close the file and remove the folder this writer made. A write cut
        short (a corrupt source in ``tlessbot rebag``, Ctrl-C in ``tlessbot simulate``) then
        leaves no half-written bag that would read as corrupt later, nor a folder that a
        second try would refuse as existing."""
        if self._file is None:
            return
        self._file.abort()
        self._file = None
        shutil.rmtree(self.path, ignore_errors=True)

    def open(self) -> None:
        file_type = _McapFile if self.storage == 'mcap' else _Sqlite3File
        self._file = file_type(self.path, self.compress)

    def add_topic(self, topic: str, msgtype: str, offers: Iterable[QosOffer] = ()) -> None:
        """Declare a topic before writing to it; ``offers`` are the QoS profiles its publishers
        offered (what ``ros2 bag play`` offers again)."""
        from rosbags.typesys import TypesysError

        if topic in self.topics:
            raise BagError(f'topic {topic} added twice')
        try:
            msgdef, _ = self.typestore.generate_msgdef(msgtype, ros_version=2)
            type_hash = self.typestore.hash_rihs01(msgtype)
        except TypesysError:
            raise BagError(f'message type {msgtype} of {topic} is unknown to the bag writer')\
                from None
        entry = _Topic(msgtype, tuple(offers), type_hash)
        entry.handle = self._opened().add_topic(topic, entry, msgdef)
        self.topics[topic] = entry

    def write(self, topic: str, log_time_ns: int, raw: bytes) -> None:
        """Append one message's serialized CDR bytes, received at ``log_time_ns``."""
        entry = self.topics.get(topic)
        if entry is None:
            raise BagError(f'topic {topic} was not added to the bag')
        self._opened().write(entry.handle, int(log_time_ns), raw)
        entry.count += 1
        self._span.add(int(log_time_ns))

    @property
    def counts(self) -> dict[str, int]:
        """Messages written per topic."""
        return {topic: entry.count for topic, entry in self.topics.items()}

    def close(self) -> None:
        """Finish the file and write ``metadata.yaml``."""
        self._opened().finish(self)
        self._file = None

    def bagfile_information(self) -> dict[str, Any]:
        """``rosbag2_bagfile_information`` as rosbag2 Jazzy writes it (key order included)."""
        file_name = self._opened().name
        start = self._span.start or 0
        duration = {'nanoseconds': (self._span.end or 0) - start}
        starting_time = {'nanoseconds_since_epoch': start}
        total = sum(self.counts.values())
        return {
            'version': METADATA_VERSION,
            'storage_identifier': self.storage,
            'duration': duration,
            'starting_time': starting_time,
            'message_count': total,
            'topics_with_message_count': [
                {'topic_metadata': {
                    'name': topic, 'type': entry.msgtype, 'serialization_format': 'cdr',
                    'offered_qos_profiles': [offer.as_rosbag2() for offer in entry.offers],
                    'type_description_hash': entry.type_hash},
                 'message_count': entry.count}
                for topic, entry in self.topics.items()],
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [file_name],
            'files': [{'path': file_name, 'starting_time': starting_time,
                       'duration': duration, 'message_count': total}],
            'custom_data': None,
            'ros_distro': ROS_DISTRO,
        }

    def _opened(self) -> _McapFile | _Sqlite3File:
        if self._file is None:
            raise BagError(f'bag {self.path} is not open')
        return self._file


class _McapFile:
    """The bag's mcap file, written with the ``mcap`` package."""

    def __init__(self, folder: Path, compress: bool) -> None:
        from mcap.writer import CompressionType, Writer

        self.name = f'{folder.name}.mcap'
        self.folder = folder
        folder.mkdir(parents=True)
        self._stream: BinaryIO = (folder / self.name).open('xb')
        self._writer = Writer(self._stream, chunk_size=CHUNK_BYTES,
                              compression=CompressionType.ZSTD if compress
                              else CompressionType.NONE)
        self._writer.start(profile='ros2', library=f'tlessbot_ros {__version__}')
        self._schemas: dict[str, int] = {}

    def add_topic(self, topic: str, entry: _Topic, msgdef: str) -> int:
        if entry.msgtype not in self._schemas:
            encoding = 'ros2idl' if msgdef.startswith('=' * 80 + '\nIDL: ') else 'ros2msg'
            self._schemas[entry.msgtype] = self._writer.register_schema(
                entry.msgtype, encoding, msgdef.encode())
        return self._writer.register_channel(
            topic, 'cdr', self._schemas[entry.msgtype], metadata=channel_metadata(entry.offers,
                                                                                   entry.type_hash))

    def write(self, channel: int, log_time_ns: int, raw: bytes) -> None:
        self._writer.add_message(channel, log_time=log_time_ns, data=bytes(raw),
                                 publish_time=log_time_ns)

    def finish(self, bag: BagWriter) -> None:
        information = bag.bagfile_information()
        self._writer.add_metadata('rosbag2',
                                  {'serialized_metadata': dump_rosbag2_yaml(information)})
        self._writer.finish()
        self._stream.close()
        write_metadata_yaml(self.folder, information)

    def abort(self) -> None:
        self._stream.close()


def channel_metadata(offers: Iterable[QosOffer], type_hash: str) -> dict[str, str]:
    """An mcap channel's metadata as rosbag2's MCAP plugin writes it."""
    return {'offered_qos_profiles': dump_rosbag2_yaml([o.as_rosbag2() for o in offers]),
            'topic_type_hash': type_hash}


def write_metadata_yaml(folder: Path, information: Mapping[str, Any]) -> None:
    """``folder/metadata.yaml``, written whole or not at all."""
    text = dump_rosbag2_yaml({'rosbag2_bagfile_information': dict(information)}) + '\n'
    temporary = folder / 'metadata.yaml.tmp'
    temporary.write_text(text, encoding='utf-8')
    temporary.replace(folder / 'metadata.yaml')


class _Sqlite3File:
    """The bag's sqlite3 database, written by rosbags (which also writes metadata.yaml)."""

    def __init__(self, folder: Path, compress: bool) -> None:
        from rosbags.rosbag2 import StoragePlugin, Writer

        del compress  # rosbag2 compresses sqlite3 bags per file or message only: none here
        self._writer = Writer(folder, version=METADATA_VERSION,
                              storage_plugin=StoragePlugin.SQLITE3)
        self._writer.open()
        self.name = f'{folder.name}.db3'

    def add_topic(self, topic: str, entry: _Topic, msgdef: str) -> Any:
        return self._writer.add_connection(
            topic, entry.msgtype, msgdef=msgdef, rihs01=entry.type_hash,
            offered_qos_profiles=[_rosbags_qos(offer) for offer in entry.offers])

    def write(self, connection: Any, log_time_ns: int, raw: bytes) -> None:
        self._writer.write(connection, log_time_ns, raw)

    def finish(self, bag: BagWriter) -> None:
        del bag  # rosbags keeps its own counts and writes metadata.yaml
        self._writer.close()

    def abort(self) -> None:
        self._writer.abort()


def _rosbags_qos(offer: QosOffer) -> Any:
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    return Qos(QosHistory[offer.history.upper()], offer.depth,
               QosReliability[offer.reliability.upper()],
               QosDurability[offer.durability.upper()], QosTime(*offer.deadline),
               QosTime(*offer.lifespan), QosLiveliness[offer.liveliness.upper()],
               QosTime(*offer.liveliness_lease_duration),
               offer.avoid_ros_namespace_conventions)
