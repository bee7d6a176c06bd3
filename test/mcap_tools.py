"""Reading mcap files as Foxglove's Python readers do (mcap + mcap-ros2-support), in tests."""
from pathlib import Path

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def decoded_messages(mcap: Path) -> list:
    """(channel, message record, decoded ROS message) of every message in log-time order."""
    with Path(mcap).open('rb') as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        return [(channel, message, ros_msg)
                for _, channel, message, ros_msg in reader.iter_decoded_messages()]


def channels(mcap: Path) -> dict:
    """Topic -> mcap Channel record (its metadata holds the QoS and type hash)."""
    with Path(mcap).open('rb') as stream:
        return {c.topic: c for c in make_reader(stream).get_summary().channels.values()}
