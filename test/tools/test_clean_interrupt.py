"""echo's QoS follows the publishers, and Ctrl-C ends echo, replay and record cleanly (real
processes over DDS)."""
import signal
import sys

import numpy as np
import pytest
from bagutil import write_bag
from running import Running, unclean_lines

from tlessbot_ros.conversions import RosbagsFactory, array_to_image, transform_to_pose_stamped
from tlessbot_ros.core.common import make_transform

pytestmark = [pytest.mark.ros]

CLI = [sys.executable, '-m', 'tlessbot_ros.tools.cli']
POSE_TOPIC = '/objects/obj_07/pose'
IMAGE_TOPIC = '/side/color/image_raw'

# A PoseStamped publisher (durability, frame_id) or a subscriber of a topic; both spin until
# Ctrl-C and say when they are up.
_PEER = """
import sys
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from tlessbot_ros.nodes.common import init_ros, message_class
role, topic = sys.argv[1], sys.argv[2]
init_ros()
node = rclpy.create_node('test_peer')
pose = message_class('geometry_msgs/msg/PoseStamped')
if role == 'publisher':
    durability = getattr(DurabilityPolicy, sys.argv[3])
    publisher = node.create_publisher(pose, topic, QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=durability))
    msg = pose()
    msg.header.frame_id = sys.argv[4]
    node.create_timer(0.2, lambda: publisher.publish(msg))
else:
    node.create_subscription(pose, topic, lambda msg: None, 10)
print(role, 'up', flush=True)
try:
    while rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.1)
except KeyboardInterrupt:
    pass
node.destroy_node()
rclpy.try_shutdown()
"""


def _peer(*args: str) -> Running:
    peer = Running([sys.executable, '-c', _PEER, *args])
    assert peer.wait_for(' up', 60), peer.output
    return peer


@pytest.fixture
def pose_bag(tmp_path):
    """Five poses, each with a small image, 50 ms apart."""
    factory = RosbagsFactory()
    image = array_to_image(np.zeros((4, 6, 3), np.uint8), 'rgb8', frame_id='side',
                           factory=factory)
    messages = []
    for i in range(5):
        stamp = (i + 1) * 50_000_000
        messages.append((POSE_TOPIC, stamp, transform_to_pose_stamped(
            make_transform(np.eye(3), [0.1 * i, 0.0, 0.5]), frame_id='side_color_optical_frame',
            stamp_ns=stamp, factory=factory)))
        messages.append((IMAGE_TOPIC, stamp + 1, image))
    return write_bag(tmp_path / 'poses', messages)


def test_echo_matching_the_publishers():
    from types import SimpleNamespace

    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from tlessbot_ros.tools.commands.echo import matches_all, matching_qos

    def info(reliable: bool, transient: bool):
        return SimpleNamespace(qos_profile=QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE if reliable
            else ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.TRANSIENT_LOCAL if transient
            else DurabilityPolicy.VOLATILE))

    latched = matching_qos([info(True, True)])
    assert (latched.reliability, latched.durability) == (ReliabilityPolicy.RELIABLE,
                                                         DurabilityPolicy.TRANSIENT_LOCAL)
    mixed = matching_qos([info(True, True), info(False, False)])
    assert (mixed.reliability, mixed.durability) == (ReliabilityPolicy.BEST_EFFORT,
                                                     DurabilityPolicy.VOLATILE)
    nobody = matching_qos([])   # never transient-local over zero publishers
    assert nobody.durability == DurabilityPolicy.VOLATILE
    assert matches_all(latched, [info(True, True)])
    assert not matches_all(latched, [info(True, True), info(True, False)])
    assert matches_all(mixed, [info(True, True), info(False, False)])


@pytest.mark.rosbag
def test_echo_started_before_the_publisher_gets_its_messages(pose_bag):
    """The topic exists (a node subscribes it) but nobody publishes yet: echo waits for the
    publisher and takes its QoS (it chose transient-local and never matched before)."""
    subscriber = _peer('subscriber', POSE_TOPIC)
    echo = Running([*CLI, 'echo', POSE_TOPIC, '--csv', '--count', '5', '--timeout', '90'])
    replay = None
    try:
        assert echo.wait_for('echo: waiting for a publisher on', 60), echo.output
        replay = Running([*CLI, 'replay', str(pose_bag), '--loop', '--rate', '2',
                          '--topics', POSE_TOPIC, '--no-wait'])
        code = echo.wait(120)
    finally:
        for process in (replay, subscriber):
            if process is not None:
                process.interrupt()
        echo.kill()
    assert code == 0, echo.output
    rows = [line for line in echo.output.splitlines() if ',side_color_optical_frame,' in line]
    assert len(rows) == 5, echo.output


def test_echo_subscribes_again_when_a_publisher_it_cannot_match_appears():
    latched = _peer('publisher', POSE_TOPIC, 'TRANSIENT_LOCAL', 'latched_frame')
    echo = Running([*CLI, 'echo', POSE_TOPIC])
    volatile = None
    try:
        assert echo.wait_for('frame: latched_frame', 60), echo.output
        volatile = _peer('publisher', POSE_TOPIC, 'VOLATILE', 'volatile_frame')
        assert echo.wait_for('subscribed again (reliable, volatile)', 60), echo.output
        assert echo.wait_for('frame: volatile_frame', 60), echo.output
        assert echo.interrupt() == 0, echo.output
    finally:
        for process in (echo, latched, volatile):
            if process is not None:
                process.kill()
    assert not unclean_lines(echo.output), echo.output


@pytest.mark.rosbag
@pytest.mark.parametrize('how', [signal.SIGINT, signal.SIGTERM])
def test_replay_echo_and_record_end_cleanly_when_interrupted(pose_bag, tmp_path, how):
    """Ctrl-C (or SIGTERM) while the replay publishes as fast as it can and echo and record
    receive: each exits 0 with no traceback and no error line, and the bag is complete."""
    replay = Running([*CLI, 'replay', str(pose_bag), '--loop', '--rate', '50',
                      '--wait-for-subscribers', '1'])
    echo = Running([*CLI, 'echo', POSE_TOPIC])
    record = Running([*CLI, 'record', POSE_TOPIC, IMAGE_TOPIC, '--out', str(tmp_path / 'rec'),
                      '--discovery-timeout', '60'])
    tools = {'replay': replay, 'echo': echo, 'record': record}
    try:
        assert record.wait_for('recording 2 topic(s)', 90), record.output
        assert echo.wait_for('frame: side_color_optical_frame', 90, count=20), echo.output
        assert record.wait_for(f'first message on {POSE_TOPIC}', 90), record.output
        for tool in tools.values():
            tool.signal_group(how)
        codes = {name: tool.wait(60) for name, tool in tools.items()}
    finally:
        for tool in tools.values():
            tool.kill()
    for name, tool in tools.items():
        assert codes[name] == 0, f'{name}:\n{tool.output}'
        assert not unclean_lines(tool.output), f'{name}:\n{tool.output}'
    assert 'recorded /objects/obj_07/pose: ' in record.output

    from tlessbot_ros.io.bags import read_bag

    assert len(list(read_bag(tmp_path / 'rec', [POSE_TOPIC]))) >= 1


def test_a_terminated_graph_command_stops_the_nodes_it_started():
    """SIGTERM to the tool alone (as `timeout` or `kill` send it, not to its process group)
    stops the graph it started (``init_ros`` turns it into KeyboardInterrupt before the
    nodes start): nodes left running would answer the next run's frames a second time."""
    import time

    import psutil

    demo = Running([*CLI, 'demo'])
    tool = psutil.Process(demo.process.pid)
    deadline = time.monotonic() + 120
    nodes: list[psutil.Process] = []
    while len(nodes) < 3 and time.monotonic() < deadline and demo.process.poll() is None:
        nodes = [child for child in tool.children(recursive=True)
                 if any('tlessbot_ros.nodes.' in part for part in child.cmdline())]
        time.sleep(0.2)
    assert len(nodes) >= 3, demo.output
    demo.process.send_signal(signal.SIGTERM)
    assert demo.wait(90) is not None, demo.output
    _, alive = psutil.wait_procs(nodes, timeout=30)
    assert not alive, [node.cmdline() for node in alive]


def test_a_signal_inside_a_recorded_write_waits_for_the_message(tmp_path):
    """Ctrl-C that comes while `tlessbot record` appends a message lets the message finish,
    then stops the loop: the bag closed afterwards reads back whole. (Raised inside the mcap
    writer, the interrupt once left a half-written record and an unreadable bag.)"""
    from tlessbot_ros.io.bag_writer import RELIABLE_OFFER, BagWriter
    from tlessbot_ros.io.bags import read_bag
    from tlessbot_ros.nodes import common
    from tlessbot_ros.tools.commands.record import message_recorder

    factory = RosbagsFactory()
    pose = transform_to_pose_stamped(np.eye(4), frame_id='top', stamp_ns=5, factory=factory)
    raw = bytes(factory.typestore.serialize_cdr(pose, pose.__msgtype__))
    writer = BagWriter(tmp_path / 'rec')
    writer.open()
    writer.add_topic(POSE_TOPIC, 'geometry_msgs/msg/PoseStamped', [RELIABLE_OFFER])
    mcap_writer = writer._file._writer
    add_message = mcap_writer.add_message

    def interrupted_add_message(*args, **kwargs):
        signal.raise_signal(signal.SIGINT)             # Ctrl-C halfway through the write
        sum(range(10_000))                             # more bytecodes: the handler has run
        return add_message(*args, **kwargs)

    mcap_writer.add_message = interrupted_add_message
    counts = {POSE_TOPIC: 0}
    on_raw = message_recorder(writer, POSE_TOPIC, counts)
    saved = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        assert common.interrupt_on_signals()
        try:
            on_raw(raw)
        except KeyboardInterrupt:
            pytest.fail('the interrupt cut the write in half')
        with pytest.raises(KeyboardInterrupt):
            common.raise_if_interrupted()              # the spin loop stops after the turn
    finally:
        common._SIGNALS_RECEIVED.clear()
        for signum, handler in saved.items():
            signal.signal(signum, handler)
    writer.close()
    assert counts == {POSE_TOPIC: 1}
    assert [m.topic for m in read_bag(tmp_path / 'rec')] == [POSE_TOPIC]
