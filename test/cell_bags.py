"""Bags as a cell records them, made from the demo bag for the approve / check tests."""
from pathlib import Path

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from tlessbot_ros.conversions.cdr import header_stamp_ns
from tlessbot_ros.io.bags import read_bag
from tlessbot_ros.tools.support.defaults import DEFAULT_BAG

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
CAMERA_TOPICS = ('color/image_raw', 'color/camera_info', 'aligned_depth_to_color/image_raw',
                 'aligned_depth_to_color/camera_info')


def cell_bag(path: Path, prefixes: dict[str, str], *, storage=StoragePlugin.SQLITE3,
             frames: int = 3, drop: tuple[str, ...] = ()) -> Path:
    """The demo bag's first ``frames`` camera frames as a cell records them with realsense-ros
    and ``ros2 bag record``: topics under ``prefixes``, each message logged a few ms after its
    stamp (one frame over many log times), written by rosbags (not tlessbot's writer).
    ``drop``: topics to leave out (``top/color/image_raw``), or one frame's message of a topic
    (``top/color/image_raw@1``)."""
    stamps: list[int] = []
    messages = []
    for message in read_bag(DEFAULT_BAG):
        camera, _, relative = message.topic[1:].partition('/')
        if camera not in prefixes or relative not in CAMERA_TOPICS:
            continue
        stamp = header_stamp_ns(message.raw)
        if stamp not in stamps:
            stamps.append(stamp)
        index = stamps.index(stamp)
        if index >= frames or {f'{camera}/{relative}', f'{camera}/{relative}@{index}'} & \
                set(drop):
            continue
        lag_ns = 1_000_000 * (1 + (len(messages) * 7) % 9)
        messages.append((stamp + lag_ns, f'{prefixes[camera]}/{relative}', message))
    writer = Writer(path, version=9, storage_plugin=storage)
    with writer:
        connections = {}
        for log_ns, topic, message in sorted(messages, key=lambda m: m[0]):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, message.msgtype,
                                                           typestore=TYPESTORE)
            writer.write(connections[topic], log_ns, message.raw)
    return path
