"""Writing tiny bags in tests, with rosbags (a writer independent of tlessbot's)."""
from pathlib import Path

from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def write_bag(path: Path, messages: list[tuple[str, int, object]], *,
              storage: StoragePlugin = StoragePlugin.MCAP,
              per_message_zstd: bool = False) -> Path:
    """messages: (topic, log time ns, rosbags message) in time order. ``per_message_zstd``
    writes a bag the way tlessbot did before it compressed chunks: every message its own zstd
    frame (rosbag2 'message' compression)."""
    writer = Writer(path, version=9, storage_plugin=storage)
    if per_message_zstd:
        writer.set_compression(CompressionMode.MESSAGE, CompressionFormat.ZSTD)
    with writer:
        connections = {}
        for topic, t_ns, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__,
                                                           typestore=TYPESTORE)
            writer.write(connections[topic], t_ns, TYPESTORE.serialize_cdr(msg, msg.__msgtype__))
    return path
