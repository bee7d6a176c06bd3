"""Print messages of a topic (like `ros2 topic echo`); PoseStamped as position, quaternion, RPY.

The message type is found from the ROS graph, and the QoS is chosen to match the publishers, as
``ros2 topic echo`` does: echo waits until the topic has a publisher, then subscribes reliable
only if every publisher is reliable and transient-local only if every publisher is; a
publisher that comes later with a QoS the subscription cannot match makes it subscribe again.

    tlessbot echo /objects/obj_05/pose
    tlessbot echo /objects/obj_05/pose --csv --timeout 10
    tlessbot echo /top/color/camera_info --once
"""
from __future__ import annotations

import argparse
import difflib
import math
import sys
import time
from functools import partial
from typing import Any

import numpy as np

from tlessbot_ros.core.common import matrix_from_quaternion, rpy_from_matrix
from tlessbot_ros.errors import TlessbotError

CSV_HEADER = 'stamp_s,frame_id,x,y,z,qx,qy,qz,qw,roll_deg,pitch_deg,yaw_deg'


def pose_fields(msg: Any) -> dict[str, Any]:
    """The numbers echo prints: stamp (s), frame, position (m), quaternion, RPY (deg)."""
    p, q = msg.pose.position, msg.pose.orientation
    quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    rpy = np.degrees(rpy_from_matrix(matrix_from_quaternion(quat))) \
        if np.linalg.norm(quat) > 0 else np.full(3, math.nan)
    return {
        'stamp_s': msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9,
        'frame_id': msg.header.frame_id,
        'position': (p.x, p.y, p.z),
        'quaternion': (q.x, q.y, q.z, q.w),
        'rpy_deg': tuple(float(v) for v in rpy),
    }


def format_pose(msg: Any) -> str:
    """Human-readable block for one PoseStamped."""
    f = pose_fields(msg)
    x, y, z = f['position']
    qx, qy, qz, qw = f['quaternion']
    roll, pitch, yaw = f['rpy_deg']
    return (f'stamp: {f["stamp_s"]:.9f}  frame: {f["frame_id"]}\n'
            f'  position [m]:   x={x:+.4f} y={y:+.4f} z={z:+.4f}\n'
            f'  quaternion:     x={qx:+.5f} y={qy:+.5f} z={qz:+.5f} w={qw:+.5f}\n'
            f'  rpy [deg]:      roll={roll:+.2f} pitch={pitch:+.2f} yaw={yaw:+.2f}')


def format_pose_csv(msg: Any) -> str:
    """One CSV row matching :data:`CSV_HEADER`."""
    f = pose_fields(msg)
    numbers = [*f['position'], *f['quaternion'], *f['rpy_deg']]
    return f'{f["stamp_s"]:.9f},{f["frame_id"]},' + ','.join(f'{v:.6f}' for v in numbers)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('topic', help='topic name, e.g. /objects/obj_05/pose')
    parser.add_argument('--once', action='store_true', help='print one message and exit')
    parser.add_argument('--csv', action='store_true', help='CSV rows (PoseStamped only)')
    parser.add_argument('--timeout', type=float, default=None, metavar='S',
                        help='exit with an error if nothing arrives for this long')
    parser.add_argument('--count', type=int, default=0, help='exit after N messages')


# echo tells the user it waits for a publisher once it found none for this long (discovery
# of one that exists takes a moment); then it looks at the publishers' QoS this often.
WAITING_NOTICE_S = 1.0
QOS_CHECK_PERIOD_S = 0.5


def missing_topic_hint(topic: str, names: list[str]) -> str:
    """For a ``topic`` the graph lacks, the graph's topics (``names``) close to it, as
    ``did you mean A or B?`` (a mistyped part name in /objects/<name>/pose); '' when it
    exists or nothing is close."""
    if topic in names:
        return ''
    close = difflib.get_close_matches(topic, names, n=3, cutoff=0.8)
    return f'did you mean {" or ".join(close)}?' if close else ''


def _wait_for_publisher(node: Any, topic: str, deadline: float | None,
                        timeout_s: float | None) -> str:
    """The type of ``topic`` once it has a publisher (the QoS is chosen from the publishers)."""
    import rclpy

    from tlessbot_ros.nodes.common import spin_once_or_interrupt

    noticed_at = time.monotonic() + WAITING_NOTICE_S
    while True:
        types = dict(node.get_topic_names_and_types())
        if types.get(topic) and node.count_publishers(topic):
            return types[topic][0]
        if noticed_at is not None and time.monotonic() > noticed_at:
            hint = missing_topic_hint(topic, sorted(types))
            print(f'echo: waiting for a publisher on {topic}'
                  + (f' (not in the graph yet; {hint})' if hint else ''), file=sys.stderr,
                  flush=True)
            noticed_at = None
        if deadline is not None and time.monotonic() > deadline:
            if topic not in types:
                hint = missing_topic_hint(topic, sorted(types))
                raise TlessbotError(f'topic {topic} does not exist in the ROS graph'
                                    + (f'; {hint}' if hint else ''))
            raise TlessbotError(f'no publisher on {topic} within {timeout_s} s')
        spin_once_or_interrupt(partial(rclpy.spin_once, node, timeout_sec=0.1))


def matching_qos(publishers: list[Any]) -> Any:
    """The subscription QoS that matches every publisher (their endpoint infos' ``qos_profile``):
    reliable only if all are reliable, transient-local only if all are (a best-effort or
    volatile subscription matches any publisher, but gets no retransmission or history)."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    offered = [info.qos_profile for info in publishers]
    reliable = bool(offered) and all(q.reliability == ReliabilityPolicy.RELIABLE
                                     for q in offered)
    transient = bool(offered) and all(q.durability == DurabilityPolicy.TRANSIENT_LOCAL
                                      for q in offered)
    return QoSProfile(depth=10,
                      reliability=ReliabilityPolicy.RELIABLE if reliable
                      else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if transient
                      else DurabilityPolicy.VOLATILE)


def matches_all(profile: Any, publishers: list[Any]) -> bool:
    """Whether a subscription with ``profile`` matches every one of ``publishers``."""
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy

    for info in publishers:
        offered = info.qos_profile
        if profile.reliability == ReliabilityPolicy.RELIABLE and \
                offered.reliability != ReliabilityPolicy.RELIABLE:
            return False
        if profile.durability == DurabilityPolicy.TRANSIENT_LOCAL and \
                offered.durability != DurabilityPolicy.TRANSIENT_LOCAL:
            return False
    return True


class _Subscription:
    """echo's subscription, made again with a wider QoS when a publisher it cannot match
    appears."""

    def __init__(self, node: Any, msg_class: type, topic: str, callback: Any) -> None:
        self._node, self._msg_class, self._topic, self._callback = \
            node, msg_class, topic, callback
        self.profile = matching_qos(node.get_publishers_info_by_topic(topic))
        self._subscription = node.create_subscription(msg_class, topic, callback, self.profile)
        self._next_check = time.monotonic() + QOS_CHECK_PERIOD_S

    def follow_publishers(self) -> None:
        if time.monotonic() < self._next_check:
            return
        self._next_check = time.monotonic() + QOS_CHECK_PERIOD_S
        publishers = self._node.get_publishers_info_by_topic(self._topic)
        if matches_all(self.profile, publishers):
            return
        self.profile = matching_qos(publishers)
        self._node.destroy_subscription(self._subscription)
        self._subscription = self._node.create_subscription(
            self._msg_class, self._topic, self._callback, self.profile)
        print(f'echo: a publisher on {self._topic} offers another QoS; subscribed again '
              f'({self.profile.reliability.name.lower()}, '
              f'{self.profile.durability.name.lower()})', file=sys.stderr, flush=True)


def run(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from tlessbot_ros.nodes.common import (
        format_message,
        init_ros,
        message_class,
        spin_once_or_interrupt,
    )

    topic = args.topic if args.topic.startswith('/') else '/' + args.topic
    init_ros()
    node = rclpy.create_node('tlessbot_echo')
    received = 0
    try:
        deadline = time.monotonic() + args.timeout if args.timeout else None
        type_name = _wait_for_publisher(node, topic, deadline, args.timeout)
        is_pose = type_name == 'geometry_msgs/msg/PoseStamped'
        if args.csv and not is_pose:
            raise TlessbotError(f'--csv prints PoseStamped only; {topic} is {type_name}')
        if args.csv:
            print(CSV_HEADER, flush=True)

        def on_message(msg: Any) -> None:
            nonlocal received, deadline
            received += 1
            if args.csv:
                print(format_pose_csv(msg), flush=True)
            else:
                print(format_pose(msg) if is_pose else format_message(msg), '\n---', flush=True)
            if args.timeout:
                deadline = time.monotonic() + args.timeout

        subscription = _Subscription(node, message_class(type_name), topic, on_message)
        limit = 1 if args.once else args.count
        while rclpy.ok() and not (limit and received >= limit):
            spin_once_or_interrupt(partial(rclpy.spin_once, node, timeout_sec=0.1))
            subscription.follow_publishers()
            if deadline is not None and time.monotonic() > deadline:
                if received == 0:
                    raise TlessbotError(f'no message on {topic} within {args.timeout} s')
                break
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
        sys.stdout.flush()
    return 0
