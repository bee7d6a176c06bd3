"""Writing tiny bags in tests."""
from pathlib import Path

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def write_bag(path: Path, messages: list[tuple[str, int, object]], *,
              storage: StoragePlugin = StoragePlugin.MCAP) -> Path:
    """messages: (topic, log time ns, rosbags message) in time order."""
    with Writer(path, version=9, storage_plugin=storage) as writer:
        connections = {}
        for topic, t_ns, msg in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msg.__msgtype__,
                                                           typestore=TYPESTORE)
            writer.write(connections[topic], t_ns, TYPESTORE.serialize_cdr(msg, msg.__msgtype__))
    return path
