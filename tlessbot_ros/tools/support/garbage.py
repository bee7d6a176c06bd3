"""Garbage for the perception graph's inputs: malformed messages at rate (bench fuzz, tests).

Every input topic of every stage gets its own stream of malformed messages: wrong or unknown
encodings, 0x0 and 4K (3840x2160) images, truncated data, a step too small, all-NaN and
all-zero depth, CameraInfo with K = 0, width 0 or NaN, unknown frame ids, bytes that are not
CDR, and frame outcomes that name no outcome. Each message's stamp is one of: zero, negative,
far in the past (the 1970s), far in the future, or recent but at least :data:`GUARD_S` before
now. A graph replaying a bag with ``--restamp`` stamps its good frames with the time they are
sent, so no garbage stamp is within any synchronisation slop of a good frame: what garbage does
to the good frames is what it does to the node, not a legitimate mix-up of stamps.

Beside the per-topic streams, whole two-view frames (every camera topic of both cameras at one
garbage stamp, one message corrupted: :func:`corrupt_frames`) reach the stages' processing.

Run as a process (``python -m tlessbot_ros.tools.support.garbage``, by ``tlessbot bench fuzz``)
so its publishing does not compete with the replay for the interpreter lock; it prints one JSON
line when it starts publishing and one with its counts at the end.
"""
from __future__ import annotations

import argparse
import copy
import itertools
import json
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tlessbot_ros.conversions.cdr import restamp_cdr
from tlessbot_ros.conversions.image_cdr import image_to_cdr
from tlessbot_ros.conversions.topics import (
    COLOR,
    DEPTH,
    DEPTH_INFO,
    camera_topic,
    classes_topic,
    labels_topic,
    outcome_topic,
    relay_topic,
)
from tlessbot_ros.core.common import CAMERA_NAMES

# Recent garbage is stamped at least this long before now: far outside every slop and age
# threshold (SyncParams: tens of milliseconds), so it never pairs with a good frame.
GUARD_S = 10.0
SECOND_NS = 1_000_000_000
# The coherent garbage frames' stamps are spread over this many seconds before the guard.
FRAME_SPREAD_S = 1000.0
UHD = (2160, 3840)     # 4K: rows, columns
VGA = (480, 640)
# Garbage that arrives on one topic alone never pairs into a frame, so its size matters only to
# the transport: it is small (at 100 Hz on 18 topics, VGA-sized garbage would measure the
# shared-memory transport, not the nodes). Full-size NaN, zero and mislabelled images reach the
# stages' processing in the coherent frames (:func:`corrupt_frames`).
SMALL = (48, 64)
RESTAMP_PERIOD_S = 1.0
IMAGE = 'sensor_msgs/msg/Image'
CAMERA_INFO = 'sensor_msgs/msg/CameraInfo'
HEADER = 'std_msgs/msg/Header'
# Role of an image topic -> the encoding its subscribers expect
ROLE_ENCODINGS = {'color': 'rgb8', 'depth': '16UC1', 'labels': '16UC1', 'classes': '16UC3'}
FRAME_CASES = ('wrong_encoding', 'size_mismatch', 'empty', 'all_nan', 'all_zero',
               'unknown_frame', 'k_zero')


@dataclass(frozen=True)
class GarbageTopic:
    """An input topic and what garbage it gets: its type and, for images, its role."""

    topic: str
    msgtype: str
    role: str = ''


def garbage_topics(cameras=CAMERA_NAMES) -> list[GarbageTopic]:
    """Every input topic of the three stages: the cameras' and their relay by the localiser,
    labels, classes and the downstream frame outcomes."""
    topics = []
    for camera in cameras:
        for name in (camera_topic, relay_topic):
            topics += [GarbageTopic(name(camera, COLOR), IMAGE, 'color'),
                       GarbageTopic(name(camera, DEPTH), IMAGE, 'depth'),
                       GarbageTopic(name(camera, DEPTH_INFO), CAMERA_INFO)]
        topics += [GarbageTopic(labels_topic(camera), IMAGE, 'labels'),
                   GarbageTopic(classes_topic(camera), IMAGE, 'classes')]
    return topics + [GarbageTopic(outcome_topic(stage), HEADER)
                     for stage in ('classifier', 'pose_estimator')]


def _filled(shape: tuple[int, int], encoding: str, value: float) -> np.ndarray:
    channels = {'rgb8': 3, '16UC3': 3}.get(encoding, 1)
    dtype = {'rgb8': np.uint8, '32FC1': np.float32}.get(encoding, np.uint16)
    return np.full(shape + ((channels,) if channels > 1 else ()), value, dtype)


def _patched_image(encoding: str, shape: tuple[int, int], **fields: int) -> bytes:
    """An Image whose height, width, step (``fields``) disagree with its data."""
    from rclpy.serialization import serialize_message

    from tlessbot_ros.conversions import array_to_image

    msg = array_to_image(_filled((4, 4), encoding, 1), encoding)
    msg.height, msg.width = shape
    for name, value in fields.items():
        setattr(msg, name, value)
    return serialize_message(msg)


def image_garbage(role: str) -> dict[str, bytes]:
    """Malformed Images for a topic of ``role`` (color, depth, labels, classes): CDR, stamp 0."""
    right = ROLE_ENCODINGS[role]
    wrong = '32FC1' if right != '32FC1' else 'rgb8'
    return {
        'wrong_encoding': image_to_cdr(_filled(SMALL, wrong, 1), wrong),
        'unknown_encoding': _unknown_encoding(),
        'zero_size': _patched_image(right, (0, 0), step=0, data=[]),
        'truncated': _patched_image(right, VGA),
        'step_too_small': _patched_image(right, (4, 4), step=1),
        'huge_4k': image_to_cdr(_filled(UHD, right, 1), right),
        'all_nan_depth': image_to_cdr(_filled(SMALL, '32FC1', np.nan), '32FC1'),
        'all_zero_depth': image_to_cdr(_filled(SMALL, '16UC1', 0), '16UC1'),
        'unknown_frame': image_to_cdr(_filled(SMALL, right, 1), right,
                                      frame_id='no_such_frame'),
        'not_cdr': bytes(range(200, 256)) * 4,
        'too_short': b'\x00\x01\x00\x00\x01',
    }


def _unknown_encoding() -> bytes:
    from rclpy.serialization import serialize_message

    from tlessbot_ros.conversions import array_to_image

    msg = array_to_image(_filled((4, 4), 'rgb8', 1), 'rgb8')
    msg.encoding = 'no_such_encoding'
    return serialize_message(msg)


def camera_info_garbage() -> dict[str, bytes]:
    """Malformed CameraInfos: CDR, stamp 0."""
    from rclpy.serialization import serialize_message

    from tlessbot_ros.conversions import intrinsics_to_camera_info
    from tlessbot_ros.core.common import d415_intrinsics

    def info(edit: Callable[[Any], None]) -> bytes:
        msg = intrinsics_to_camera_info(d415_intrinsics(VGA[1], VGA[0]),
                                        frame_id='side_color_optical_frame')
        edit(msg)
        return serialize_message(msg)

    return {
        'k_zero': info(lambda m: setattr(m, 'k', np.zeros(9))),
        'width_zero': info(lambda m: setattr(m, 'width', 0)),
        'k_nan': info(lambda m: setattr(m, 'k', np.full(9, np.nan))),
        'huge_size': info(lambda m: (setattr(m, 'width', UHD[1]), setattr(m, 'height', UHD[0]))),
        'unknown_frame': info(lambda m: setattr(m.header, 'frame_id', 'no_such_frame')),
        'many_distortion': info(lambda m: setattr(m, 'd', np.ones(10_000))),
        'not_cdr': bytes(range(200, 256)) * 4,
        'too_short': b'\x00\x01\x00\x00',
    }


def outcome_garbage() -> dict[str, bytes]:
    """Frame-outcome Headers that name no outcome, or name one for a frame nobody took."""
    from rclpy.serialization import serialize_message

    from tlessbot_ros.conversions.messages import make_header

    return {
        'not_an_outcome': serialize_message(make_header('no_such_outcome', 0)),
        'empty_frame_id': serialize_message(make_header('', 0)),
        'done_for_no_frame': serialize_message(make_header('done', 0)),
        'failed_for_no_frame': serialize_message(make_header('failed', 0)),
        'not_cdr': bytes(range(200, 256)),
        'too_short': b'\x00\x01',
    }


def garbage_stamp(kind: str, now_ns: int, rng: np.random.Generator) -> int:
    """A stamp of ``kind`` (zero, negative, past, future, recent) that no good frame has."""
    jitter = int(rng.integers(0, 5 * SECOND_NS))
    return {'zero': 0, 'negative': -SECOND_NS - jitter, 'past': SECOND_NS + jitter,
            'future': now_ns + 100_000_000 * SECOND_NS + jitter,   # about three years ahead
            'recent': now_ns - int(GUARD_S * SECOND_NS) - jitter}[kind]


STAMP_KINDS = ('recent', 'zero', 'past', 'future', 'negative')


def corrupt_frames(good: dict[str, Any], cases=FRAME_CASES[:6]) -> list[tuple[str, dict]]:
    """(name, messages) pairs of malformed two-view frames built from ``good`` (topic ->
    message, the camera topics of both cameras), the k-th one stamped k seconds later.
    Cases: :data:`FRAME_CASES` (the side camera's message is corrupted)."""
    from tlessbot_ros.conversions import array_to_image

    def variant(k: int, edit):
        msgs = {t: copy.deepcopy(m) for t, m in good.items()}
        for msg in msgs.values():
            msg.header.stamp.sec += k
        edit(msgs)
        return msgs

    depth_topic = camera_topic('side', DEPTH)

    def replace_depth(m, array: np.ndarray, encoding: str) -> None:
        header = m[depth_topic].header
        m[depth_topic] = array_to_image(array, encoding, frame_id=header.frame_id,
                                        stamp_ns=header.stamp.sec * SECOND_NS)

    def set_all_frames(m, frame_id: str) -> None:
        for msg in m.values():
            msg.header.frame_id = frame_id

    edits = {
        'wrong_encoding': lambda m: setattr(m[camera_topic('side', COLOR)], 'encoding', '32FC1'),
        'size_mismatch': lambda m: setattr(m[camera_topic('side', DEPTH_INFO)], 'width', 320),
        'empty': lambda m: setattr(m[depth_topic], 'data', []),
        'all_nan': lambda m: replace_depth(m, _filled(VGA, '32FC1', np.nan), '32FC1'),
        'all_zero': lambda m: replace_depth(m, _filled(VGA, '16UC1', 0), '16UC1'),
        'unknown_frame': lambda m: set_all_frames(m, 'no_such_frame'),
        'k_zero': lambda m: setattr(m[camera_topic('side', DEPTH_INFO)], 'k', np.zeros(9)),
    }
    return [(case, variant(k + 1, edits[case])) for k, case in enumerate(cases)]


@dataclass
class GarbageCounts:
    """What was sent: messages per topic and per kind, coherent frames, the ticks that ran."""

    per_topic: dict[str, int] = field(default_factory=dict)
    per_kind: dict[str, int] = field(default_factory=dict)
    frames: int = 0
    ticks: int = 0
    seconds: float = 0.0


class GarbagePublisher:
    """Publishes garbage on every topic at ``rate_hz`` each, and coherent corrupted two-view
    frames at ``frame_hz``; one 4K image every ``huge_period_s`` on some topic (each is
    16-24 MiB: at 100 Hz they would measure the transport's bandwidth, not the nodes)."""

    def __init__(self, node: Any, topics: list[GarbageTopic], *, rate_hz: float = 100.0,
                 frame_hz: float = 1.0, huge_period_s: float = 1.0,
                 good_frame: dict[str, Any] | None = None, seed: int = 0) -> None:
        from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
        from rclpy.serialization import serialize_message

        from tlessbot_ros.nodes.common import message_class

        # Reliable, as the nodes' inputs (config: input_qos reliable); keep-last 1 so a slow
        # subscriber never blocks this publisher.
        qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                         history=HistoryPolicy.KEEP_LAST, depth=1)
        self.node, self.topics, self.rate_hz = node, topics, rate_hz
        self.frame_hz, self.huge_period_s = frame_hz, huge_period_s
        self.rng = np.random.default_rng(seed)
        self.publishers = {t.topic: node.create_publisher(message_class(t.msgtype), t.topic, qos)
                           for t in topics}
        self._kinds: dict[str, Iterator[tuple[str, bytes]]] = {}
        for t in topics:
            table = image_garbage(t.role) if t.msgtype == IMAGE else \
                camera_info_garbage() if t.msgtype == CAMERA_INFO else outcome_garbage()
            self._kinds[t.topic] = itertools.cycle(list(table.items()))
        self._stamps = {t.topic: itertools.cycle(STAMP_KINDS) for t in topics}
        self._last_huge = -float('inf')   # one 4K image per huge_period_s, on any topic
        self._frames = itertools.cycle([
            {topic: serialize_message(msg) for topic, msg in msgs.items()}
            for _, msgs in corrupt_frames(good_frame, FRAME_CASES)]) if good_frame else None
        self._restamped: dict[tuple[str, int, str], tuple[float, bytes]] = {}
        self.counts = GarbageCounts()

    def _next_message(self, topic: str, now_s: float) -> tuple[str, bytes]:
        kind, raw = next(self._kinds[topic])
        if kind == 'huge_4k':
            if now_s - self._last_huge < self.huge_period_s:
                kind, raw = next(self._kinds[topic])
            else:
                self._last_huge = now_s
        return kind, raw

    def _stamped(self, topic: str, raw: bytes, stamp_kind: str, now_s: float,
                 wall_ns: int) -> bytes:
        """``raw`` with a garbage stamp of ``stamp_kind``. Copies of each message with each
        kind of stamp are kept per topic for up to :data:`RESTAMP_PERIOD_S` (copying megabytes
        for every message would cap the rate far below 100 Hz); 4K ones are sent rarely and
        not kept. Per topic: strays are strays, each topic's its own; the same garbage stamp
        on several topics, twice in line, would be whole frames on a second timeline (a second
        driver on the same topics), which the nodes take for a time jump."""
        if len(raw) > 4 * 2**20:
            return restamp_cdr(raw, garbage_stamp(stamp_kind, wall_ns, self.rng))
        key = (topic, id(raw), stamp_kind)
        made = self._restamped.get(key)
        if made is None or now_s - made[0] > RESTAMP_PERIOD_S:
            made = (now_s, restamp_cdr(raw, garbage_stamp(stamp_kind, wall_ns, self.rng)))
            self._restamped[key] = made
        return made[1]

    def tick(self, now_s: float, wall_ns: int) -> None:
        """One message on every topic."""
        for topic, publisher in self.publishers.items():
            kind, raw = self._next_message(topic, now_s)
            if len(raw) >= 12 and raw[:2] == b'\x00\x01':   # CDR: a stamp to set
                raw = self._stamped(topic, raw, next(self._stamps[topic]), now_s, wall_ns)
            publisher.publish(raw)
            self.counts.per_topic[topic] = self.counts.per_topic.get(topic, 0) + 1
            self.counts.per_kind[kind] = self.counts.per_kind.get(kind, 0) + 1

    def send_frame(self, wall_ns: int) -> None:
        """One coherent two-view frame with one corrupted message, at a garbage stamp from the
        last :data:`FRAME_SPREAD_S` before the recent guard: the frames are strays, each on its
        own, and rarely in line with the one before (frames stamped alike on every topic, one
        after the other in line, would be a second timeline: a time jump)."""
        stamp = wall_ns - int((GUARD_S + self.rng.uniform(0.0, FRAME_SPREAD_S)) * SECOND_NS)
        for topic, raw in next(self._frames).items():
            if topic in self.publishers:
                self.publishers[topic].publish(restamp_cdr(raw, stamp))
        self.counts.frames += 1

    def run(self, duration_s: float, should_stop: Callable[[], bool] = lambda: False) -> None:
        """Publish for ``duration_s`` seconds (ticks that fall behind are skipped, not
        bunched: the rate reached is ``counts.ticks / counts.seconds``)."""
        start = time.monotonic()
        period = 1.0 / self.rate_hz
        next_tick, next_frame = start, start
        while not should_stop():
            now = time.monotonic()
            if now - start >= duration_s:
                break
            if now < next_tick:
                time.sleep(next_tick - now)
                continue
            self.tick(now - start, time.time_ns())
            self.counts.ticks += 1
            next_tick = max(next_tick + period, time.monotonic())
            if self._frames is not None and self.frame_hz > 0 and now >= next_frame:
                self.send_frame(time.time_ns())
                next_frame = now + 1.0 / self.frame_hz
        self.counts.seconds = time.monotonic() - start


def first_camera_frame(bag: str) -> dict[str, Any]:
    """The first frame's camera messages (colour, depth, depth CameraInfo of each camera) of a
    bag, as rclpy messages."""
    from rclpy.serialization import deserialize_message

    from tlessbot_ros.io.bags import read_bag
    from tlessbot_ros.nodes.common import message_class

    wanted = {camera_topic(c, r) for c in CAMERA_NAMES for r in (COLOR, DEPTH, DEPTH_INFO)}
    frame: dict[str, Any] = {}
    for message in read_bag(bag, sorted(wanted)):
        if message.topic not in frame:
            frame[message.topic] = deserialize_message(message.raw,
                                                       message_class(message.msgtype))
        if len(frame) == len(wanted):
            break
    return frame


def main(argv: list[str] | None = None) -> int:
    """Publish garbage for ``--duration`` s; JSON lines on stdout: start, then the counts."""
    import rclpy

    from tlessbot_ros.nodes.common import init_ros

    parser = argparse.ArgumentParser(prog='garbage', description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=60.0)
    parser.add_argument('--rate', type=float, default=100.0, help='messages/s on each topic')
    parser.add_argument('--frame-rate', type=float, default=1.0,
                        help='coherent corrupted two-view frames per second')
    parser.add_argument('--huge-period', type=float, default=1.0,
                        help='seconds between 4K images (on one topic after the other)')
    parser.add_argument('--bag', default=None, help='bag whose first frame the coherent '
                                                    'frames corrupt (none: no such frames)')
    args = parser.parse_args(argv)
    init_ros()
    node = rclpy.create_node('tlessbot_garbage')
    try:
        publisher = GarbagePublisher(
            node, garbage_topics(), rate_hz=args.rate, frame_hz=args.frame_rate,
            huge_period_s=args.huge_period,
            good_frame=first_camera_frame(args.bag) if args.bag else None)
        time.sleep(1.0)   # let the publishers match the graph's subscriptions
        print(json.dumps({'started_ns': time.time_ns()}), flush=True)
        publisher.run(args.duration)
        counts = publisher.counts
        print(json.dumps({'ended_ns': time.time_ns(), 'per_topic': counts.per_topic,
                          'per_kind': counts.per_kind, 'frames': counts.frames,
                          'ticks': counts.ticks, 'seconds': counts.seconds}), flush=True)
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
