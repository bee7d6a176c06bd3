"""Publishing a rosbag2 bag's raw CDR through an rclpy node at the recorded rate (replay,
demo, evaluate --bag, bench graph)."""
from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from tlessbot_ros.conversions.cdr import header_stamp_ns, restamp_cdr, starts_with_header
from tlessbot_ros.errors import BagError
from tlessbot_ros.io.bags import BagMessage, bag_topics, read_bag


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


def wait_for_matches(node: Any, publishers: dict[str, Any], *, timeout_s: float,
                     settle_s: float = 1.0) -> dict[str, tuple[int, int]]:
    """Wait until every subscription the graph knows of on the publishers' topics has matched
    its publisher, up to ``timeout_s``; a first message sent before that is lost for a
    subscriber that has not matched yet (DDS discovery takes a moment).

    Waits for at least one subscriber somewhere (the graph may still be starting), and then
    ``settle_s`` more for late discoveries. Returns ``{topic: (matched, known)}`` for the topics
    still short of subscribers at the end: ``known == 0`` means nobody subscribes the topic;
    ``matched < known`` usually means a subscriber with an incompatible QoS.
    """
    import rclpy

    deadline = time.monotonic() + timeout_s
    settled_at = None

    def counts() -> dict[str, tuple[int, int]]:   # topic: (matched, known to the graph)
        return {topic: (publisher.get_subscription_count(), node.count_subscribers(topic))
                for topic, publisher in publishers.items()}

    while time.monotonic() < deadline:
        now = counts()
        if any(known for _, known in now.values()) and \
                all(matched >= known for matched, known in now.values()):
            settled_at = settled_at or time.monotonic() + settle_s
            if time.monotonic() >= settled_at:
                break
        else:
            settled_at = None
        rclpy.spin_once(node, timeout_sec=0.05)
    return {t: c for t, c in counts().items() if c[0] < c[1] or c[1] == 0}


def describe_unmatched(unmatched: dict[str, tuple[int, int]]) -> str:
    """One line naming the topics :func:`wait_for_matches` left short of subscribers."""
    nobody = sorted(t for t, (_, known) in unmatched.items() if known == 0)
    partial = sorted(f'{t} ({m} of {k} matched: incompatible QoS?)'
                     for t, (m, k) in unmatched.items() if k)
    parts = []
    if partial:
        parts.append('not every subscriber matched on ' + ', '.join(partial))
    if nobody:
        parts.append(f'no subscriber on {len(nobody)} topic(s): ' + ', '.join(nobody))
    return 'replay: ' + '; '.join(parts)


def wait_for_acknowledgements(publishers: dict[str, Any], *, timeout_s: float = 5.0) -> bool:
    """Wait until every reliable subscriber acknowledged what the publishers sent, up to
    ``timeout_s``: a replay that ends at once after its last message takes the messages not yet
    acknowledged with it, and a slow reliable subscriber never gets them. Waits in short steps,
    so Ctrl-C still stops it. True when all were acknowledged."""
    from rclpy.duration import Duration

    step = Duration(nanoseconds=50_000_000)
    deadline = time.monotonic() + timeout_s
    pending = list(publishers.values())
    while pending and time.monotonic() < deadline:
        pending = [publisher for publisher in pending if not publisher.wait_for_all_acked(step)]
    return not pending


def replay(node: Any, bag: str, *, rate: float = 1.0, loop: bool = False,
           topics: list[str] | None = None, qos: str = 'reliable',
           wait_for_subscribers_s: float = 0.0, restamp: bool = False,
           report: Callable[[str], None] | None = None,
           on_publish: Callable[[BagMessage], None] | None = None,
           should_stop: Callable[[], bool] = lambda: False) -> int:
    """Publish the bag's raw messages through ``node``; returns the number published.

    With ``restamp``, a header stamp becomes the ROS time at which its frame is published
    (:class:`FrameRestamper`).
    """

    from tlessbot_ros.nodes.common import (
        RESULT_QOS,
        SENSOR_QOS,
        message_class,
        raise_if_interrupted,
    )

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
        unmatched = wait_for_matches(node, publishers, timeout_s=wait_for_subscribers_s)
        if unmatched and report is not None:
            report(describe_unmatched(unmatched))
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
        if next_pass_wall is not None:
            # one reading of the clock: between a check and a second reading the wait can
            # become negative, which time.sleep refuses (a 30-minute soak died of it)
            time.sleep(max(0.0, next_pass_wall - time.monotonic()))
        start_wall, start_bag = None, None
        restamper.new_pass()
        for message in cached if cached is not None else read_bag(bag, list(types)):
            raise_if_interrupted()
            if should_stop():
                wait_for_acknowledgements(publishers)
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
            wait_for_acknowledgements(publishers)
            return published
        if start_wall is not None:
            next_pass_wall = start_wall + pass_period_ns / 1e9 / rate
