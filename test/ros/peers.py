"""Talker / listener processes for the multi-process DDS test (run as scripts).

    python peers.py talker   publishes one known Image and PoseStamped every 50 ms
    python peers.py listener prints the first Image and PoseStamped it receives as JSON, exits
"""
import hashlib
import json
import sys

import numpy as np
import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node

from tlessbot_ros.conversions import (
    array_to_image,
    image_to_array,
    pose_stamped_to_transform,
    transform_to_pose_stamped,
)
from tlessbot_ros.core.common import make_transform, rotation_about_axis

IMAGE_TOPIC = 'test/color/image_raw'
POSE_TOPIC = 'test/objects/obj_05/pose'
STAMP_NS = 1_700_000_000_250_000_000


def known_image() -> np.ndarray:
    return np.random.default_rng(7).integers(0, 256, (48, 64, 3), dtype=np.uint8)


def known_transform() -> np.ndarray:
    return make_transform(rotation_about_axis([0.2, -1.0, 0.5], 0.9), [0.125, -0.05, 0.75])


def talker() -> None:
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Image

    node = Node('peer_talker')
    image_pub = node.create_publisher(Image, IMAGE_TOPIC, 10)
    pose_pub = node.create_publisher(PoseStamped, POSE_TOPIC, 10)
    image = array_to_image(known_image(), 'rgb8', frame_id='top_color_optical_frame',
                           stamp_ns=STAMP_NS)
    pose = transform_to_pose_stamped(known_transform(), frame_id='top_color_optical_frame',
                                     stamp_ns=STAMP_NS)

    def publish() -> None:
        image_pub.publish(image)
        pose_pub.publish(pose)

    node.create_timer(0.05, publish)
    rclpy.spin(node)


def listener() -> None:
    from geometry_msgs.msg import PoseStamped
    from sensor_msgs.msg import Image

    node = Node('peer_listener')
    received: dict = {}

    def on_image(msg: Image) -> None:
        array = image_to_array(msg)
        received.setdefault('image', {
            'encoding': msg.encoding, 'shape': list(array.shape),
            'sha256': hashlib.sha256(array.tobytes()).hexdigest(),
            'frame_id': msg.header.frame_id,
            'stamp': [msg.header.stamp.sec, msg.header.stamp.nanosec]})

    def on_pose(msg: PoseStamped) -> None:
        T, frame_id, stamp_ns = pose_stamped_to_transform(msg)
        received.setdefault('pose', {'T': T.tolist(), 'frame_id': frame_id,
                                     'stamp_ns': stamp_ns,
                                     'position': [msg.pose.position.x, msg.pose.position.y,
                                                  msg.pose.position.z]})

    node.create_subscription(Image, IMAGE_TOPIC, on_image, 10)
    node.create_subscription(PoseStamped, POSE_TOPIC, on_pose, 10)
    while rclpy.ok() and len(received) < 2:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(json.dumps(received), flush=True)


if __name__ == '__main__':
    rclpy.init()
    try:
        {'talker': talker, 'listener': listener}[sys.argv[1]]()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()
