"""The Foxglove live view: a WebSocket client connects, lists the channels and decodes a pose
forwarded from ROS (CDR bytes with the ros2msg schema)."""
import json
import re
import struct
import sys
import time

import numpy as np
import pytest
from running import Running

from tlessbot_ros.conversions.messages import RclpyFactory
from tlessbot_ros.conversions.pose import transform_to_pose_stamped
from tlessbot_ros.core.common.geometry import make_transform

pytestmark = pytest.mark.ros
pytest.importorskip('foxglove')
websockets_sync = pytest.importorskip('websockets.sync.client')
TOPIC = '/objects/obj_05/pose'


def received(socket, publish, done, timeout_s=60.0):
    """The server's messages, publishing a pose before each wait, until ``done()``."""
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        publish()
        try:
            yield socket.recv(timeout=0.5)
        except TimeoutError:
            continue


def test_client_lists_channels_and_decodes_a_pose():
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rosbags.typesys import Stores, get_typestore

    view = Running([sys.executable, '-m', 'tlessbot_ros.nodes.foxglove_view', '--ros-args',
                    '-p', 'port:=0', '-p', 'scan_period_s:=0.2'])
    rclpy.init()
    node = rclpy.create_node('foxglove_test')
    publisher = node.create_publisher(PoseStamped, TOPIC, 10)
    T = make_transform(np.eye(3), np.array([0.1, -0.2, 0.3]))
    try:
        def publish():
            publisher.publish(transform_to_pose_stamped(T, frame_id='world', stamp_ns=7,
                                                        factory=RclpyFactory()))
        assert view.wait_for('Foxglove live view on ws://127.0.0.1:', 120), view.output
        port = int(re.search(r'ws://127\.0\.0\.1:(\d+)', view.output).group(1))
        # the app connects to a running view: the pose's channel is there before the client
        deadline = time.monotonic() + 60
        while f'forwarding {TOPIC}' not in view.output and time.monotonic() < deadline:
            publish()
            view.wait_for(f'forwarding {TOPIC}', 0.2)
        with websockets_sync.connect(f'ws://127.0.0.1:{port}',
                                     subprotocols=['foxglove.sdk.v1',
                                                   'foxglove.websocket.v1']) as socket:
            channels = {}
            for message in received(socket, publish, lambda: TOPIC in channels):
                if isinstance(message, str) and json.loads(message)['op'] == 'advertise':
                    for channel in json.loads(message)['channels']:
                        channels[channel['topic']] = channel
            assert TOPIC in channels, (channels, view.output)
            channel = channels[TOPIC]
            assert (channel['encoding'], channel['schemaName'], channel['schemaEncoding']) == \
                ('cdr', 'geometry_msgs/msg/PoseStamped', 'ros2msg')
            subscribe = {'op': 'subscribe',
                         'subscriptions': [{'id': 1, 'channelId': channel['id']}]}
            socket.send(json.dumps(subscribe))
            payloads, statuses = [], []
            for message in received(socket, publish, lambda: bool(payloads)):
                if isinstance(message, str):
                    statuses.append(message)
                elif message[0] == 1:   # message data
                    assert struct.unpack_from('<I', message, 1)[0] == 1
                    payloads.append(message[13:])
        assert payloads, (statuses, view.output)
        pose = get_typestore(Stores.ROS2_JAZZY).deserialize_cdr(
            payloads[0], 'geometry_msgs/msg/PoseStamped')
        assert pose.header.frame_id == 'world' and pose.header.stamp.nanosec == 7
        assert (pose.pose.position.x, pose.pose.position.y, pose.pose.position.z) == \
            pytest.approx((0.1, -0.2, 0.3))
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        view.interrupt()
