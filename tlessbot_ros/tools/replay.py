"""Publish a rosbag2 bag (mcap or sqlite3) into the ROS graph as raw CDR, at the recorded rate.

    tlessbot replay bags/demo.mcap
    tlessbot replay bags/demo.mcap --rate 0.5 --loop --topics /side/color/image_raw
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from tlessbot_ros.conversions.cdr import header_stamp_ns, restamp_cdr, starts_with_header
from tlessbot_ros.errors import BagError
from tlessbot_ros.io.bags import BagMessage, bag_topics, read_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('bag', help='bag folder or .mcap / .db3 file')
    parser.add_argument('--rate', type=float, default=1.0, help='playback speed factor')
    parser.add_argument('--loop', action='store_true', help='start again at the end')
    parser.add_argument('--topics', nargs='+', default=None, help='only these topics')
    parser.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='S',
                        help='wait up to S seconds for a subscriber on every image topic')
    parser.add_argument('--qos', choices=('reliable', 'sensor'), default='reliable',
                        help='QoS of the publishers')
    parser.add_argument('--restamp', action='store_true',
                        help='stamp each frame with the ROS time at which it is published '
                             '(its messages share the stamp; later loops move forward)')


def _loop_period_ns(messages: list[BagMessage]) -> int:
    """Span of the bag's log times plus the median gap between distinct ones."""
    times = np.unique([m.log_time_ns for m in messages])
    if len(times) < 2:
        return 0
    return int(times[-1] - times[0] + np.median(np.diff(times)))


class FrameRestamper:
    """New header stamps for a replay: the ROS time at which a frame goes out.

    Every message that shares an original stamp (one camera frame: colour, depth, infos, ground
    truth) gets the stamp given to the first of them, so frames stay consistent; a later frame
    gets a later time, across loops too. Stamping at publication, like a driver stamping at
    capture, keeps the replay's own lag out of latencies measured from the stamp.
    """

    def __init__(self) -> None:
        self._assigned: dict[int, int] = {}

    def stamp(self, original_ns: int, now_ns: int) -> int:
        if original_ns not in self._assigned:
            if len(self._assigned) >= 1000:   # bounded: forget the oldest frame, not the last
                del self._assigned[next(iter(self._assigned))]
            self._assigned[original_ns] = now_ns
        return self._assigned[original_ns]

    def new_pass(self) -> None:
        """A loop starts again: the same original stamps are new frames now."""
        self._assigned.clear()


def replay(node: Any, bag: str, *, rate: float = 1.0, loop: bool = False,
           topics: list[str] | None = None, qos: str = 'reliable',
           wait_for_subscribers_s: float = 0.0, restamp: bool = False,
           on_publish: Callable[[BagMessage], None] | None = None,
           should_stop: Callable[[], bool] = lambda: False) -> int:
    """Publish the bag's raw messages through ``node``; returns the number published.

    With ``restamp``, a header stamp becomes the ROS time at which its frame is published
    (:class:`FrameRestamper`).
    """
    import rclpy

    from tlessbot_ros.nodes.common import RESULT_QOS, SENSOR_QOS, message_class

    if rate <= 0:
        raise BagError(f'--rate must be positive, got {rate}')
    types = bag_topics(bag)
    if topics:
        missing = sorted(set(topics) - set(types))
        if missing:
            raise BagError(f'bag {bag} has no topic(s) {missing}; it has {sorted(types)}')
        types = {t: types[t] for t in topics}
    profile = SENSOR_QOS if qos == 'sensor' else RESULT_QOS
    publishers = {topic: node.create_publisher(message_class(msgtype), topic, profile)
                  for topic, msgtype in types.items()}
    if wait_for_subscribers_s > 0:
        deadline = time.monotonic() + wait_for_subscribers_s
        watched = [p for t, p in publishers.items() if types[t] == 'sensor_msgs/msg/Image']
        while time.monotonic() < deadline and not all(p.get_subscription_count() for p in watched):
            rclpy.spin_once(node, timeout_sec=0.05)
    published = 0
    # A looped bag is read once and kept in memory (decompressing it every pass would cap the
    # replay rate); bags are demo-sized here.
    cached = list(read_bag(bag, list(types))) if loop else None
    restamper = FrameRestamper()
    # A loop's next pass starts one frame interval after the last frame of this one (not at
    # once, which would replay faster than the bag's rate).
    pass_period_ns = _loop_period_ns(cached) if cached else 0
    next_pass_wall = None
    while True:
        if next_pass_wall is not None and next_pass_wall > time.monotonic():
            time.sleep(next_pass_wall - time.monotonic())
        start_wall, start_bag = None, None
        restamper.new_pass()
        for message in cached if cached is not None else read_bag(bag, list(types)):
            if should_stop():
                return published
            if start_wall is None:
                start_wall, start_bag = time.monotonic(), message.log_time_ns
            due = start_wall + (message.log_time_ns - start_bag) / 1e9 / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            if restamp and starts_with_header(message.msgtype):
                message = dataclasses.replace(message, raw=restamp_cdr(
                    message.raw, restamper.stamp(header_stamp_ns(message.raw),
                                                 node.get_clock().now().nanoseconds)))
            publishers[message.topic].publish(message.raw)
            published += 1
            if on_publish is not None:
                on_publish(message)
        if not loop or published == 0:
            return published
        if start_wall is not None:
            next_pass_wall = start_wall + pass_period_ns / 1e9 / rate


def run(args: argparse.Namespace) -> int:
    import rclpy
    from rclpy.executors import ExternalShutdownException

    from tlessbot_ros.nodes.common import init_ros

    bag_topics(args.bag)  # fail with one clear line before touching ROS
    init_ros()
    node = rclpy.create_node('tlessbot_replay')
    try:
        count = replay(node, args.bag, rate=args.rate, loop=args.loop, topics=args.topics,
                       qos=args.qos, wait_for_subscribers_s=args.wait_for_subscribers,
                       restamp=args.restamp)
        print(f'replayed {count} messages from {args.bag}')
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
