"""echo / replay / record as real processes over DDS, and their one-line errors."""
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bagutil import TYPESTORE, write_bag
from mcap.reader import make_reader
from mcap_tools import channels, decoded_messages
from rosbags.rosbag2 import StoragePlugin

from tlessbot_ros.conversions import RosbagsFactory, array_to_image, transform_to_pose_stamped
from tlessbot_ros.core.common import make_transform, rotation_about_axis
from tlessbot_ros.io.bag_writer import RELIABLE_OFFER
from tlessbot_ros.io.bags import ZSTD_FRAME_MAGIC, bag_offered_qos, read_bag
from tlessbot_ros.tools.commands.echo import CSV_HEADER, format_pose, format_pose_csv

CLI = [sys.executable, '-m', 'tlessbot_ros.tools.cli']
POSE_TOPIC = '/objects/obj_05/pose'


def _poses(count: int):
    factory = RosbagsFactory()
    return [transform_to_pose_stamped(
        make_transform(rotation_about_axis([0, 0, 1], np.radians(10 * i)), [0.1 * i, 0.2, 0.5]),
        frame_id='side_color_optical_frame', stamp_ns=(i + 1) * 50_000_000, factory=factory)
        for i in range(count)]


def test_pose_formatting():
    msg = _poses(3)[2]
    text = format_pose(msg)
    assert 'frame: side_color_optical_frame' in text and 'yaw=+20.00' in text
    row = format_pose_csv(msg).split(',')
    assert len(row) == len(CSV_HEADER.split(','))
    assert row[:3] == ['0.150000000', 'side_color_optical_frame', '0.200000']
    assert float(row[-1]) == pytest.approx(20.0)


def _pose_messages():
    """Five poses, each followed by an image, as (topic, log time ns, message)."""
    image = array_to_image(np.zeros((4, 6, 3), np.uint8), 'rgb8', frame_id='side',
                           factory=RosbagsFactory())
    messages = []
    for i, pose in enumerate(_poses(5)):
        messages.append((POSE_TOPIC, (i + 1) * 50_000_000, pose))
        messages.append(('/side/color/image_raw', (i + 1) * 50_000_000 + 1, image))
    return messages


def test_a_mistyped_part_name_gets_the_close_topics():
    from tlessbot_ros.tools.commands.echo import missing_topic_hint

    names = ['/objects/plate_holes2/pose', '/objects/plate_holes3/pose', '/objects/tube/pose',
             '/objects/markers', '/diagnostics']
    assert missing_topic_hint('/objects/plate_hole2/pose', names) == (
        'did you mean /objects/plate_holes2/pose or /objects/plate_holes3/pose?')
    assert missing_topic_hint('/objects/tube/pose', names) == ''      # it exists
    assert missing_topic_hint('/camera/points', names) == ''          # nothing close


@pytest.fixture
def pose_bag(tmp_path):
    return write_bag(tmp_path / 'poses', _pose_messages())


@pytest.fixture
def old_style_bag(tmp_path):
    """The same messages as tlessbot wrote bags before chunk compression."""
    return write_bag(tmp_path / 'old', _pose_messages(), per_message_zstd=True)


@pytest.mark.ros
@pytest.mark.rosbag
@pytest.mark.parametrize('source', ['bag', 'old-style .mcap'])
def test_replay_into_echo(source, tmp_path):
    bag = write_bag(tmp_path / 'poses', _pose_messages(), per_message_zstd=source != 'bag')
    if source != 'bag':
        bag = bag / 'poses.mcap'   # without metadata.yaml to say the messages are compressed
    echo = subprocess.Popen([*CLI, 'echo', POSE_TOPIC, '--csv', '--count', '5', '--timeout',
                             '30'], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    replay = subprocess.Popen([*CLI, 'replay', str(bag), '--loop', '--rate', '2'],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        out, err = echo.communicate(timeout=90)
    finally:
        replay.terminate()
        replay.wait(timeout=20)
    assert echo.returncode == 0, err
    lines = out.strip().splitlines()
    assert lines[0] == CSV_HEADER
    rows = [line.split(',') for line in lines[1:]]
    assert len(rows) == 5
    expected = {f'{(i + 1) * 0.05:.9f}': i for i in range(5)}
    for row in rows:
        i = expected[row[0]]  # every stamp is one of the bag's
        assert float(row[2]) == pytest.approx(0.1 * i)
        assert float(row[-1]) == pytest.approx(10 * i)


@pytest.mark.ros
@pytest.mark.rosbag
def test_record_keeps_raw_bytes(pose_bag, tmp_path):
    out = tmp_path / 'recorded'
    record = subprocess.Popen([*CLI, 'record', POSE_TOPIC, '--out', str(out), '--duration', '8',
                               '--discovery-timeout', '20'],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    replay = subprocess.Popen([*CLI, 'replay', str(pose_bag), '--loop', '--topics', POSE_TOPIC],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        _, err = record.communicate(timeout=60)
    finally:
        replay.terminate()
        replay.wait(timeout=20)
    assert record.returncode == 0, err
    originals = {m.raw for m in read_bag(pose_bag, [POSE_TOPIC])}
    recorded = [m.raw for m in read_bag(out, [POSE_TOPIC])]
    assert len(recorded) >= 3
    assert set(recorded) <= originals
    # A bag every tool reads, offering again what the replay's publisher offered.
    assert len(decoded_messages(out / 'recorded.mcap')) == len(recorded)
    channel = channels(out / 'recorded.mcap')[POSE_TOPIC]
    assert channel.metadata['topic_type_hash'] == \
        TYPESTORE.hash_rihs01('geometry_msgs/msg/PoseStamped')
    assert bag_offered_qos(out) == {POSE_TOPIC: [RELIABLE_OFFER]}


@pytest.mark.rosbag
def test_old_style_bags_read_as_plain_cdr(pose_bag, old_style_bag):
    old_mcap = old_style_bag / 'old.mcap'
    with old_mcap.open('rb') as stream:
        stored = [m.data for _, _, m in make_reader(stream).iter_messages()]
    assert all(data.startswith(ZSTD_FRAME_MAGIC) for data in stored)   # really per-message zstd
    expected = [(m.topic, m.log_time_ns, m.raw) for m in read_bag(pose_bag)]
    for path in (old_style_bag, old_mcap):
        assert [(m.topic, m.log_time_ns, m.raw) for m in read_bag(path)] == expected


@pytest.mark.rosbag
def test_rebag_makes_old_bags_readable_by_every_tool(tmp_path, old_style_bag):
    out = tmp_path / 'new'
    result = _run('rebag', str(old_style_bag / 'old.mcap'), str(out))
    assert result.returncode == 0, result.stderr
    assert 'rewrote 10 messages on 2 topics' in result.stdout
    assert [(m.topic, m.log_time_ns, m.raw) for m in read_bag(out)] == \
        [(m.topic, m.log_time_ns, m.raw) for m in read_bag(old_style_bag)]
    decoded = decoded_messages(out / 'new.mcap')
    assert [ros_msg.header.frame_id for _, _, ros_msg in decoded] == \
        ['side_color_optical_frame', 'side'] * 5
    assert channels(out / 'new.mcap')['/side/color/image_raw'].metadata['topic_type_hash'] == \
        TYPESTORE.hash_rihs01('sensor_msgs/msg/Image')
    again = _run('rebag', str(old_style_bag), str(out))
    assert again.returncode == 1 and again.stderr.strip().splitlines() == [
        f'tlessbot rebag: error: output bag {out} exists; choose a new path']


def _run(*args):
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=60)


def test_replay_errors_are_one_line(tmp_path, pose_bag):
    missing = _run('replay', str(tmp_path / 'nope.mcap'))
    assert missing.returncode == 1
    assert missing.stderr.strip().splitlines() == [
        f'tlessbot replay: error: bag not found: {tmp_path / "nope.mcap"}']
    corrupt = tmp_path / 'corrupt.mcap'
    corrupt.write_bytes(b'\x89MCAP0\r\n' + bytes(range(256)) * 4)
    result = _run('replay', str(corrupt))
    assert result.returncode == 1 and len(result.stderr.strip().splitlines()) == 1
    assert 'cannot open bag' in result.stderr or 'corrupt' in result.stderr
    result = _run('replay', str(pose_bag), '--topics', '/not/there')
    assert result.returncode == 1 and "no topic(s) ['/not/there']" in result.stderr


def test_truncated_bag_raises_bag_error(tmp_path, pose_bag):
    from tlessbot_ros.errors import BagError

    mcap = next(Path(pose_bag).glob('*.mcap'))
    data = mcap.read_bytes()
    mcap.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError):
        list(read_bag(pose_bag))


def test_sqlite_bags_read_too(tmp_path):
    bag = write_bag(tmp_path / 'sq', [(POSE_TOPIC, 1, _poses(1)[0])],
                    storage=StoragePlugin.SQLITE3)
    (message,) = list(read_bag(bag))
    assert TYPESTORE.deserialize_cdr(message.raw, message.msgtype).header.frame_id == \
        'side_color_optical_frame'


def test_restamp_rewrites_only_the_stamp(pose_bag):
    from tlessbot_ros.conversions.cdr import header_stamp_ns, restamp_cdr, starts_with_header

    for message in read_bag(pose_bag):
        assert starts_with_header(message.msgtype)
        original = TYPESTORE.deserialize_cdr(message.raw, message.msgtype)
        assert header_stamp_ns(message.raw) == \
            original.header.stamp.sec * 10**9 + original.header.stamp.nanosec
        moved = TYPESTORE.deserialize_cdr(restamp_cdr(message.raw, 1_800_000_000_123_456_789),
                                          message.msgtype)
        assert (moved.header.stamp.sec, moved.header.stamp.nanosec) == (1_800_000_000,
                                                                        123_456_789)
        assert moved.header.frame_id == original.header.frame_id
    assert not starts_with_header('std_msgs/msg/String')


def test_restamped_replay_stamps_a_frame_when_it_goes_out():
    from tlessbot_ros.tools.support.replay import FrameRestamper

    restamper = FrameRestamper()
    first = restamper.stamp(1_000, now_ns=5_000)
    assert restamper.stamp(1_000, now_ns=5_900) == first == 5_000   # same frame, same stamp
    assert restamper.stamp(2_000, now_ns=6_000) == 6_000            # next frame: its own time
    restamper.new_pass()
    assert restamper.stamp(1_000, now_ns=9_000) == 9_000            # a loop: a new frame
    for original in range(2_000, 2_000 + 1_500):                     # a long bag: bounded,
        restamper.stamp(original, now_ns=original)                    # but the newest frame
    assert restamper.stamp(3_499, now_ns=0) == 3_499                  # keeps its stamp


_LISTENER = """
import sys, time
import rclpy
from tlessbot_ros.nodes.common import RESULT_QOS, init_ros, message_class
init_ros()
node = rclpy.create_node('replay_listener')
stamps = []
node.create_subscription(message_class('geometry_msgs/msg/PoseStamped'), sys.argv[1],
                         lambda m: stamps.append(m.header.stamp.nanosec), RESULT_QOS)
print('subscribed', flush=True)
deadline = time.monotonic() + 60
while len(stamps) < int(sys.argv[2]) and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
print(' '.join(map(str, stamps)), flush=True)
"""


@pytest.mark.ros
@pytest.mark.rosbag
def test_replay_waits_until_the_existing_subscribers_have_matched(pose_bag):
    """Started right after a subscriber, a replay (no loop) loses not even its first message,
    and names the bag's topics nobody subscribes."""
    listener = subprocess.Popen([sys.executable, '-c', _LISTENER, POSE_TOPIC, '5'],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert listener.stdout.readline().strip() == 'subscribed'
        replay = _run('replay', str(pose_bag), '--rate', '4')
        out, err = listener.communicate(timeout=90)
    finally:
        listener.kill()
    assert replay.returncode == 0, replay.stderr
    assert 'no subscriber on 1 topic(s): /side/color/image_raw' in replay.stdout
    assert POSE_TOPIC not in replay.stdout.split('replayed')[0]
    assert out.split() == [str((i + 1) * 50_000_000) for i in range(5)], err


@pytest.mark.rosbag
def test_rebag_of_a_corrupt_bag_leaves_no_half_bag(tmp_path, old_style_bag):
    """The last message's zstd frame damaged: rebag fails on it in one line, after writing the
    messages before it, and removes its output instead of leaving a bag that reads as corrupt."""
    mcap = old_style_bag / 'old.mcap'
    data = bytearray(mcap.read_bytes())
    last_frame = data.rfind(ZSTD_FRAME_MAGIC)
    data[last_frame + 4:last_frame + 12] = b'\xff' * 8
    mcap.write_bytes(bytes(data))
    out = tmp_path / 'new'
    result = _run('rebag', str(old_style_bag), str(out))
    assert result.returncode == 1
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and 'is corrupt or truncated' in lines[0], result.stderr
    assert not out.exists()
