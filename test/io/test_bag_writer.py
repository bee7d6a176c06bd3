"""Bags every tool reads: the committed bags decode with mcap-ros2-support (what Foxglove reads),
and a freshly written bag is what rosbag2 (Jazzy) writes: zstd chunks of plain CDR, type hashes
and offered QoS on the channels, rosbag2's metadata.yaml and serialized_metadata."""
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader
from mcap_tools import channels, decoded_messages

from tlessbot_ros.conversions import RosbagsFactory, array_to_image, transform_to_pose_stamped
from tlessbot_ros.core.common import make_transform
from tlessbot_ros.errors import BagError
from tlessbot_ros.io.bag_writer import RELIABLE_OFFER, BagWriter, QosOffer
from tlessbot_ros.io.bags import bag_offered_qos, read_bag

pytestmark = pytest.mark.rosbag

REPO = Path(__file__).resolve().parents[2]
COMMITTED_MCAPS = sorted((REPO / 'bags').glob('**/*.mcap'))
# sensor_msgs/msg/Image's REP-2011 hash in ROS 2 Jazzy, as rosidl publishes it in
# share/sensor_msgs/msg/Image.json ("type_hashes") of the Jazzy sensor_msgs package.
IMAGE_RIHS01 = 'RIHS01_d31d41a9a4c4bc8eae9be757b0beed306564f7526c88ea6a4588fb9582527d47'
IMAGE_TOPIC, POSE_TOPIC = '/side/color/image_raw', '/ground_truth/obj_05'
ROSBAG2_KEYS = ['version', 'storage_identifier', 'duration', 'starting_time', 'message_count',
                'topics_with_message_count', 'compression_format', 'compression_mode',
                'relative_file_paths', 'files', 'custom_data', 'ros_distro']
SENSOR_OFFER = QosOffer('keep_last', 5, 'best_effort', 'volatile', (0, 0), (0, 0),
                        'system_default', (0, 0))


def _metadata(folder: Path) -> dict:
    return yaml.safe_load((folder / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


@pytest.mark.parametrize('mcap', COMMITTED_MCAPS, ids=lambda p: str(p.relative_to(REPO)))
def test_every_message_of_the_committed_bags_decodes_with_mcap_ros2(mcap):
    counts: dict[str, int] = {}
    for channel, _, ros_msg in decoded_messages(mcap):
        assert ros_msg is not None
        counts[channel.topic] = counts.get(channel.topic, 0) + 1
    info = _metadata(mcap.parent)
    expected = {t['topic_metadata']['name']: t['message_count']
                for t in info['topics_with_message_count']}
    assert counts == expected
    assert sum(counts.values()) == info['message_count']


def test_there_are_committed_bags():
    assert REPO / 'bags' / 'demo' / 'demo.mcap' in COMMITTED_MCAPS


@pytest.fixture(scope='module')
def written(tmp_path_factory):
    """A small bag: 3 frames of an rgb8 image and a pose; returns (folder, messages)."""
    factory = RosbagsFactory()
    store = factory.typestore
    rng = np.random.default_rng(7)
    folder = tmp_path_factory.mktemp('bags') / 'small'
    messages = []
    with BagWriter(folder, typestore=store) as bag:
        bag.add_topic(IMAGE_TOPIC, 'sensor_msgs/msg/Image', [RELIABLE_OFFER])
        bag.add_topic(POSE_TOPIC, 'geometry_msgs/msg/PoseStamped', [RELIABLE_OFFER, SENSOR_OFFER])
        for i in range(3):
            stamp = 1_700_000_000_000_000_000 + i * 100_000_000
            image = array_to_image(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8), 'rgb8',
                                   frame_id='side_color_optical_frame', stamp_ns=stamp,
                                   factory=factory)
            pose = transform_to_pose_stamped(make_transform(np.eye(3), [0.1 * i, 0.0, 0.6]),
                                             frame_id='side_color_optical_frame',
                                             stamp_ns=stamp, factory=factory)
            for topic, msg in ((IMAGE_TOPIC, image), (POSE_TOPIC, pose)):
                raw = bytes(store.serialize_cdr(msg, msg.__msgtype__))
                bag.write(topic, stamp, raw)
                messages.append((topic, stamp, raw))
    return folder, messages


def test_chunks_are_zstd_and_messages_plain_cdr(written):
    folder, messages = written
    with (folder / 'small.mcap').open('rb') as stream:
        records = list(StreamReader(stream, emit_chunks=True, validate_crcs=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert chunks and {c.compression for c in chunks} == {'zstd'}
    assert not [r for r in records if isinstance(r, Message)]  # every message is in a chunk
    with (folder / 'small.mcap').open('rb') as stream:
        stored = [(channel.topic, m.log_time, m.data)
                  for _, channel, m in make_reader(stream).iter_messages()]
    assert stored == messages   # the CDR bytes as written: no per-message compression
    assert all(raw[:2] == b'\x00\x01' for _, _, raw in stored)   # CDR little-endian header


def test_channels_carry_type_hash_qos_and_ros2msg_schemas(written):
    folder, _ = written
    with (folder / 'small.mcap').open('rb') as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        header = reader.get_header()
    assert header.profile == 'ros2'
    by_topic = channels(folder / 'small.mcap')
    image = by_topic[IMAGE_TOPIC]
    assert image.message_encoding == 'cdr'
    assert image.metadata['topic_type_hash'] == IMAGE_RIHS01
    assert yaml.safe_load(image.metadata['offered_qos_profiles']) == \
        [RELIABLE_OFFER.as_rosbag2()]
    assert yaml.safe_load(by_topic[POSE_TOPIC].metadata['offered_qos_profiles']) == \
        [RELIABLE_OFFER.as_rosbag2(), SENSOR_OFFER.as_rosbag2()]
    schema = summary.schemas[image.schema_id]
    assert (schema.name, schema.encoding) == ('sensor_msgs/msg/Image', 'ros2msg')
    assert b'MSG: std_msgs/Header' in schema.data


def _jazzy_share() -> Path | None:
    """The share folder of the ROS 2 message packages (a ROS install or the PyPI wheels)."""
    prefixes = [*filter(None, os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)),
                sys.prefix]
    return next((Path(p) / 'share' for p in prefixes
                 if (Path(p) / 'share' / 'sensor_msgs' / 'msg' / 'Image.json').is_file()), None)


def test_type_hashes_are_the_ones_ros_publishes(written):
    share = _jazzy_share()
    if share is None:
        pytest.skip('no ROS 2 message packages with type descriptions installed')
    published = json.loads((share / 'sensor_msgs' / 'msg' / 'Image.json').read_text())
    assert published['type_hashes'][0]['hash_string'] == IMAGE_RIHS01
    folder, _ = written
    with (folder / 'small.mcap').open('rb') as stream:
        summary = make_reader(stream).get_summary()
    for channel in summary.channels.values():
        package, _, name = summary.schemas[channel.schema_id].name.split('/')
        description = json.loads((share / package / 'msg' / f'{name}.json').read_text())
        assert channel.metadata['topic_type_hash'] == \
            description['type_hashes'][0]['hash_string']


def test_mcap_ros2_decodes_what_was_written(written):
    folder, messages = written
    decoded = decoded_messages(folder / 'small.mcap')
    assert [(channel.topic, m.log_time) for channel, m, _ in decoded] == \
        [(topic, stamp) for topic, stamp, _ in messages]
    for _, message, ros_msg in decoded:
        stamp = ros_msg.header.stamp
        assert stamp.sec * 10**9 + stamp.nanosec == message.log_time
        assert ros_msg.header.frame_id == 'side_color_optical_frame'
    poses = [ros_msg for channel, _, ros_msg in decoded if channel.topic == POSE_TOPIC]
    assert [p.pose.position.x for p in poses] == pytest.approx([0.0, 0.1, 0.2])


def test_metadata_yaml_is_rosbag2s(written):
    folder, messages = written
    info = _metadata(folder)
    assert list(info) == ROSBAG2_KEYS
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['compression_format'] == '' and info['compression_mode'] == ''
    assert info['ros_distro'] == 'jazzy' and info['custom_data'] is None
    assert info['message_count'] == len(messages) == 6
    assert info['starting_time'] == {'nanoseconds_since_epoch': 1_700_000_000_000_000_000}
    assert info['duration'] == {'nanoseconds': 200_000_000}
    assert info['relative_file_paths'] == ['small.mcap']
    assert info['files'] == [{'path': 'small.mcap', 'starting_time': info['starting_time'],
                              'duration': info['duration'], 'message_count': 6}]
    image = info['topics_with_message_count'][0]
    assert image == {'topic_metadata': {
        'name': IMAGE_TOPIC, 'type': 'sensor_msgs/msg/Image', 'serialization_format': 'cdr',
        'offered_qos_profiles': [RELIABLE_OFFER.as_rosbag2()],
        'type_description_hash': IMAGE_RIHS01}, 'message_count': 3}
    text = (folder / 'metadata.yaml').read_text()
    assert 'compression_mode: ""' in text and 'custom_data: ~' in text   # as yaml-cpp writes
    assert '&' not in text   # no YAML anchors


def test_the_mcap_carries_the_same_metadata(written):
    """rosbag2 reads its metadata from the mcap when metadata.yaml is missing."""
    folder, _ = written
    with (folder / 'small.mcap').open('rb') as stream:
        records = {m.name: m.metadata for m in make_reader(stream).iter_metadata()}
    assert yaml.safe_load(records['rosbag2']['serialized_metadata']) == _metadata(folder)


def test_rosbags_reads_it_with_and_without_metadata_yaml(written):
    folder, messages = written
    for path in (folder, folder / 'small.mcap'):
        assert [(m.topic, m.log_time_ns, m.raw) for m in read_bag(path)] == messages
    assert bag_offered_qos(folder) == {IMAGE_TOPIC: [RELIABLE_OFFER],
                                       POSE_TOPIC: [RELIABLE_OFFER, SENSOR_OFFER]}


def test_uncompressed_and_sqlite3_bags(tmp_path, written):
    _, messages = written
    for storage, compress in (('mcap', False), ('sqlite3', True)):
        folder = tmp_path / storage
        with BagWriter(folder, storage=storage, compress=compress) as bag:
            bag.add_topic(POSE_TOPIC, 'geometry_msgs/msg/PoseStamped', [SENSOR_OFFER])
            for topic, stamp, raw in messages:
                if topic == POSE_TOPIC:
                    bag.write(topic, stamp, raw)
        assert [m.raw for m in read_bag(folder)] == [r for t, _, r in messages if t == POSE_TOPIC]
        assert bag_offered_qos(folder) == {POSE_TOPIC: [SENSOR_OFFER]}
        assert _metadata(folder)['storage_identifier'] == storage
    with (tmp_path / 'mcap' / 'mcap.mcap').open('rb') as stream:
        assert {c.compression for c in make_reader(stream).get_summary().chunk_indexes} == {''}


def test_writer_errors(tmp_path):
    with pytest.raises(BagError, match='exists'):
        BagWriter(tmp_path)
    with pytest.raises(BagError, match='unknown bag storage'):
        BagWriter(tmp_path / 'x', storage='rosbag1')
    with BagWriter(tmp_path / 'b') as bag:
        with pytest.raises(BagError, match='unknown to the bag writer'):
            bag.add_topic('/a', 'foo_msgs/msg/Bar')
        with pytest.raises(BagError, match='was not added'):
            bag.write('/a', 1, b'\x00\x01\x00\x00')
        bag.add_topic('/a', 'std_msgs/msg/String')
        with pytest.raises(BagError, match='added twice'):
            bag.add_topic('/a', 'std_msgs/msg/String')
    assert _metadata(tmp_path / 'b')['message_count'] == 0


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_a_bag_given_up_is_removed(tmp_path, written, storage):
    """An error inside ``with BagWriter(...)`` removes the folder it made, half-written file and
    all, and lets the error through."""
    _, messages = written
    folder = tmp_path / 'cut'
    with pytest.raises(RuntimeError, match='source failed'):
        with BagWriter(folder, storage=storage) as bag:
            bag.add_topic(POSE_TOPIC, 'geometry_msgs/msg/PoseStamped', [SENSOR_OFFER])
            bag.write(*next(m for m in messages if m[0] == POSE_TOPIC))
            raise RuntimeError('source failed')
    assert not folder.exists()
    BagWriter(folder)                                 # a second try is not refused
