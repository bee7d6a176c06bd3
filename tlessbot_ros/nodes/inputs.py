"""Two-view input synchronisation for the perception nodes.

Each camera's topics (e.g. colour, aligned depth, camera_info) are paired by stamp through a
bounded :class:`~tlessbot_ros.core.common.StampSynchroniser`; complete per-camera sets are then
paired across cameras under ``max_age_s``. The callback gets
``{camera: {topic_key: RawMessage}}``; :func:`deserialise_views` turns them into messages.
Everything is bounded: old frames are dropped and counted.

Every topic's stamps are watched for jumps (:class:`~tlessbot_ros.core.common.StampJumps`,
``sync.jump_back_s`` / ``sync.jump_forward_s``): a bag looped without restamping, a camera
clock that steps. At a jump every queue is emptied, the old timeline's late messages are
dropped, and the node is told (``on_time_jump``) so it can forget what it keyed by stamp.

The subscriptions are raw: a message is kept as its CDR bytes and only its header stamp is
read, so the many camera frames a slow stage skips are never turned into Python messages, and
what is deserialised is deserialised on the stage's worker thread, not the executor's.

A gate (the graph's entrance, while it is full) can keep the subscriptions out of the
executor's wait set altogether (:class:`GatedCallbackGroup`): their messages then stay unread
in the DDS history, where newer ones replace older ones at no cost to Python, and
:meth:`TwoViewInputs.reopen` reads what waited once the gate opens and passes on only its newest
complete frame. Taking each message through rclpy's SingleThreadedExecutor costs far more
than its bytes: the executor rebuilds its wait set for every message taken
(docs/bench/backpressure.md, docs/bench/code-figures.md). rclpy's EventsExecutor
(``sync.executor: events``, the default) has no such turn and ignores callback groups: it
delivers every message, and those that come while the gate is closed are kept as the DDS
history would keep them (the QoS depth per topic, the newest) and read the same way when it
opens.
"""
from __future__ import annotations

import threading
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.node import Node

from tlessbot_ros.conversions.cdr import header_stamp_ns
from tlessbot_ros.conversions.image import ENCODINGS
from tlessbot_ros.conversions.image_cdr import image_from_cdr
from tlessbot_ros.core.common import (
    JUMP,
    SkippedFrames,
    StampJumps,
    StampSynchroniser,
    SyncParams,
    TimelineGate,
)
from tlessbot_ros.nodes.qos import SENSOR_QOS

Views = dict[str, dict[str, Any]]


@dataclass(frozen=True)
class RawMessage:
    """A message as received: its rclpy class and CDR bytes."""

    msg_class: type
    data: bytes

    def deserialise(self) -> Any:
        """The message; an Image is read in place (:mod:`~tlessbot_ros.conversions.image_cdr`,
        no copy of its pixels), any other type through rclpy."""
        if _is_image(self.msg_class):
            return image_from_cdr(self.data)
        from rclpy.serialization import deserialize_message

        return deserialize_message(self.data, self.msg_class)


def _is_image(msg_class: type) -> bool:
    return msg_class.__name__ == 'Image' and msg_class.__module__.startswith('sensor_msgs.')


def deserialise_views(views: Views) -> Views:
    """``{camera: {key: RawMessage | message}}`` -> the same with messages (a corrupt message
    raises here, in the stage's error handling)."""
    return {camera: {key: msg.deserialise() if isinstance(msg, RawMessage) else msg
                     for key, msg in msgs.items()} for camera, msgs in views.items()}


def newest_stamp_ns(views: Views) -> int | None:
    """The newest header stamp (ns) among the received messages of a frame (None: none raw)."""
    stamps = [header_stamp_ns(msg.data) for msgs in views.values() for msg in msgs.values()
              if isinstance(msg, RawMessage)]
    return max(stamps) if stamps else None


def check_input(data: bytes, msg_class: type, max_mb: float) -> None:
    """Refuse, before it is queued, an input no stage could use: larger than ``max_mb`` MiB
    (0: no limit), or an Image whose CDR, size or encoding is broken (a known encoding that is
    wrong for the stage is the stage's to refuse).

    Raises:
        ValueError: saying why.
    """
    if max_mb > 0 and len(data) > max_mb * 2**20:
        raise ValueError(f'message of {len(data) / 2**20:.1f} MiB is larger than '
                         f'sync.max_message_mb = {max_mb:g}')
    if not _is_image(msg_class):
        return
    image = image_from_cdr(data)
    if image.encoding not in ENCODINGS:
        raise ValueError(f'unsupported image encoding {image.encoding!r}')
    if image.height == 0 or image.width == 0 or image.step == 0:
        raise ValueError(f'image has zero size ({image.width}x{image.height}, step '
                         f'{image.step})')
    if image.data.size != image.height * image.step:
        raise ValueError(f'image data has {image.data.size} bytes, expected height*step = '
                         f'{image.height * image.step}')


class GatedCallbackGroup(MutuallyExclusiveCallbackGroup):
    """A callback group whose entities wait while ``is_open()`` is False: rclpy's executor
    builds its wait set from ``can_execute`` at every turn, so a closed group's subscriptions
    are neither waited on nor taken, and their messages stay in the DDS history. A gate that
    opens is seen at the executor's next turn (any event, its poll timeout, or a guard
    condition such as :meth:`TwoViewInputs.reopen`'s)."""

    def __init__(self, is_open: Callable[[], bool]) -> None:
        super().__init__()
        self._is_open = is_open

    def can_execute(self, entity: Any) -> bool:
        return self._is_open() and super().can_execute(entity)


def _stamp_or_zero(data: bytes) -> int:
    """A raw message's header stamp for ordering (0 when unreadable: its handler refuses it)."""
    try:
        return header_stamp_ns(data)
    except ValueError:
        return 0


class TwoViewInputs:
    """Subscribes ``/<camera>/<topic>`` for every camera and topic, emits synchronised views.

    Args:
        node: the owning node (subscriptions are created on it).
        topics: topic key -> (message class, camera name -> topic name), e.g.
            ``{'color': (Image, lambda camera: camera_topic(camera, COLOR))}``
            (:mod:`tlessbot_ros.conversions.topics`).
        cameras: camera names; all must contribute to a view set.
        sync: thresholds; ``slop_s`` within a camera, ``max_age_s`` across cameras.
        callback: called with the views of one two-view frame, and whether the frame was held
            while a time jump waited for its confirmation (``SyncParams.jump_confirmations``):
            such frames come several at once and should all be processed, in order.
        qos: subscription QoS (sensor data by default).
        on_time_jump: called with the jump's size (ns, < 0 back) when stamps jump, after the
            queues were emptied.
        gate: while it returns False, no message is read (see ``pause_in_dds``); call
            :meth:`reopen` when it may have opened. None: every message is taken as it comes.
        pause_in_dds: while the gate is closed, leave the messages in the DDS history
            (:class:`GatedCallbackGroup`, and a guard condition that carries :meth:`reopen` to
            the executor's thread): for rclpy's SingleThreadedExecutor, which asks the
            callback groups. False: take every message and keep those that come while the gate
            is closed (as many per topic as the QoS depth, the newest), read the same way when
            it opens: at once on the executor's thread, or with the next message when
            :meth:`reopen` came from another thread. That works with any executor; rclpy's
            EventsExecutor needs it (it ignores callback groups and has no guard conditions).
    """

    def __init__(self, node: Node, topics: dict[str, tuple[type, Callable[[str], str]]],
                 cameras: Sequence[str], sync: SyncParams,
                 callback: Callable[[Views, bool], None], *, qos: Any = SENSOR_QOS,
                 on_time_jump: Callable[[int], None] | None = None,
                 gate: Callable[[], bool] | None = None,
                 pause_in_dds: bool = True) -> None:
        self._callback = callback
        self._on_time_jump = on_time_jump
        self._stale_before = 0   # counted by gates replaced by reconfigure
        self._node, self._topics = node, topics
        self._keys, self._cameras = list(topics), list(cameras)
        self._dropped_before = 0   # by synchronisers replaced by reconfigure
        self._build_synchronisers(sync)
        self.zero_stamps = 0
        self.malformed = 0
        self.superseded = 0   # complete frames read after a pause, older than the newest
        self._skipped = SkippedFrames()   # gaps between the complete frames' stamps
        self._collected: list[tuple[Views, bool]] | None = None   # while reading a pause
        self._is_open = gate
        self._keep_newest = True
        # set by reopen() until the guard's callback has read what waited: meanwhile the
        # executor must not take the oldest waiting messages one by one itself
        self._reopening = False
        group = GatedCallbackGroup(self._readable) if gate is not None and pause_in_dds \
            else None
        # Messages an executor that ignores callback groups (rclpy's EventsExecutor) delivered
        # while the gate was closed: kept per stream as the DDS history would keep them (its
        # depth, the newest), and read with what still waits there when the gate opens.
        self._paused_depth = max(1, int(getattr(qos, 'depth', 1) or 1))
        self._delivered_while_paused: dict[tuple[str, str], deque[bytes]] = {}
        self._subscriptions = []   # (subscription, its stream (camera, key), its handler)
        for camera in cameras:
            for key, (msg_class, topic) in topics.items():
                handler = self._handler(camera, key, msg_class)
                delivered = handler if gate is None or pause_in_dds else \
                    partial(self._delivered, (camera, key), handler)
                self._subscriptions.append((node.create_subscription(
                    msg_class, topic(camera), delivered, qos, raw=True, callback_group=group),
                    (camera, key), handler))
        self._reopened = node.create_guard_condition(self._read_paused) \
            if gate is not None and pause_in_dds else None
        self._executor_thread: int | None = None   # the thread that delivers messages
        self._delivering = False   # in _delivered or _read_paused: a reopen waits for its end

    def _build_synchronisers(self, sync: SyncParams) -> None:
        self.sync = sync
        self.jumps = StampJumps(back_ns=int(sync.jump_back_s * 1e9),
                                forward_ns=int(sync.jump_forward_s * 1e9),
                                # a topic that goes on with its old timeline for as many
                                # items as confirm a jump did not jump (a false jump, from
                                # strays, must not silence the good topics for long); a few
                                # stragglers of a real one (frames in flight) are fewer
                                stale_limit=(max(3, sync.jump_confirmations + 1)
                                             if sync.jump_confirmations else sync.queue_size),
                                confirmations=sync.jump_confirmations)
        self._per_camera = {
            camera: StampSynchroniser(self._keys, slop_ns=int(sync.slop_s * 1e9),
                                      queue_size=sync.queue_size) for camera in self._cameras}
        self._across = StampSynchroniser(self._cameras, slop_ns=int(sync.max_age_s * 1e9),
                                         queue_size=2)
        self._gate = TimelineGate(self.jumps, [*self._per_camera.values(), self._across])

    def reconfigure(self, sync: SyncParams) -> None:
        """New thresholds (call from the thread that delivers messages). When ``slop_s``,
        ``queue_size`` or ``max_age_s`` change, pairing starts again: messages waiting for
        partners are dropped (and counted)."""
        old, self.sync = self.sync, sync
        if (old.slop_s, old.queue_size, old.max_age_s, old.jump_back_s, old.jump_forward_s,
                old.jump_confirmations) == (sync.slop_s, sync.queue_size, sync.max_age_s,
                                            sync.jump_back_s, sync.jump_forward_s,
                                            sync.jump_confirmations):
            return
        self._dropped_before += self._paired_dropped() + self.waiting
        self._stale_before = self.stale
        self._build_synchronisers(sync)

    @property
    def waiting(self) -> int:
        """Messages and camera sets held while they wait for partners."""
        return sum(sum(s.pending().values())
                   for s in (self._across, *self._per_camera.values()))

    def _delivered(self, stream: tuple[str, str], handler: Callable[[bytes], None],
                   data: bytes) -> None:
        """A gated subscription's message without ``pause_in_dds``: handled now if the gate is
        open, else kept for :meth:`_read_paused`; a :meth:`reopen` that came meanwhile is
        carried out after it, with this message read last."""
        self._executor_thread = threading.get_ident()
        self._delivering = True
        try:
            if self._readable():   # may reopen (the entrance opened meanwhile)
                handler(data)
            else:
                self._delivered_while_paused.setdefault(
                    stream, deque(maxlen=self._paused_depth)).append(data)
        finally:
            self._delivering = False
        self._read_if_reopened()

    def _read_if_reopened(self) -> None:
        """Carry out a :meth:`reopen` that came while a message was being handled (no guard
        condition: rclpy's EventsExecutor)."""
        while self._reopening and self._reopened is None and not self._delivering:
            self._delivering = True
            try:
                self._read_paused()
            finally:
                self._delivering = False

    def _handler(self, camera: str, key: str, msg_class: type) -> Callable[[bytes], None]:
        topic = self._topics[key][1](camera)

        def on_message(data: bytes) -> None:
            try:
                stamp = header_stamp_ns(data)
                check_input(data, msg_class, self.sync.max_message_mb)
            except ValueError as error:
                # never queued, so it cannot push a good message out; counted in diagnostics
                self.malformed += 1
                self._node.get_logger().warning(f'{topic}: {error}; ignored',
                                                throttle_duration_sec=5.0)
                return
            if stamp == 0:
                self.zero_stamps += 1  # cannot be synchronised; counted in diagnostics
                return
            verdict, released = self._gate.admit((camera, key), stamp,
                                                 RawMessage(msg_class, data))
            if verdict == JUMP and self._on_time_jump is not None:
                self._on_time_jump(self.jumps.last_jump_ns)
            # more than one: messages held while a jump waited for confirmation come too
            held = len(released) > 1
            for (from_camera, from_key), from_stamp, message in released:
                self._pair(from_camera, from_key, from_stamp, message, held)
        return on_message

    def _pair(self, camera: str, key: str, stamp: int, message: RawMessage,
              held: bool) -> None:
        """Queue one message for pairing; a complete set of every camera goes to the
        callback (``held``: it was completed by messages released at a time jump)."""
        complete = self._per_camera[camera].add(key, stamp, message)
        if complete is None:
            return
        views = self._across.add(camera, stamp, complete)
        if views is None:
            return
        self._count_unread(views)
        if self._collected is not None:
            self._collected.append((views, held))
        else:
            self._callback(views, held)

    def reopen(self, *, keep_newest: bool = True) -> None:
        """The gate may have opened: read, on the executor's thread, the messages that waited
        in the subscriptions and pass on the newest complete frame they hold (with
        ``keep_newest``; else none: the entrance refused them all). Any thread may call it."""
        if self._is_open is None:
            return
        self._keep_newest = keep_newest
        self._reopening = True
        if self._reopened is not None:
            self._reopened.trigger()
        elif threading.get_ident() == self._executor_thread:
            self._read_if_reopened()   # at once, unless a message is being handled

    def _readable(self) -> bool:
        return not self._reopening and self._is_open()

    def _read_paused(self) -> None:
        """Take every message waiting in the subscriptions (guard condition, executor thread),
        pair them as if they had come one by one (each topic's in the order it came, across
        topics by stamp: :meth:`~tlessbot_ros.core.common.StampJumps.reading_order`), then
        hand on the frames released at a time jump and the newest other complete frame;
        the older ones are counted in :attr:`superseded`."""
        self._reopening = False
        if not self._is_open():
            return
        waiting = {}   # per subscription, in the order its messages came
        for subscription, stream, handler in self._subscriptions:
            taken_here = waiting.setdefault(stream, [])
            delivered = self._delivered_while_paused.pop(stream, ())
            taken_here.extend((_stamp_or_zero(data), (handler, data)) for data in delivered)
            try:
                with subscription.handle:
                    while (taken := subscription.handle.take_message(
                            subscription.msg_type, True)) is not None:
                        taken_here.append((_stamp_or_zero(taken[0]), (handler, taken[0])))
            except InvalidHandle:   # destroyed: the node is shutting down
                return
        frames: list[tuple[Views, bool]] = []
        self._collected = frames
        try:
            for _, _, (handler, data) in self.jumps.reading_order(waiting):
                handler(data)
        finally:
            self._collected = None
        fresh = [views for views, held in frames if not held]
        newest = fresh[-1] if fresh and self._keep_newest else None
        self.superseded += len(fresh) - (newest is not None)
        for views, held in frames:
            if held or views is newest:
                self._callback(views, held)

    def _count_unread(self, views: Views) -> None:
        """Frames never read show as gaps between the stamps of the first camera's complete
        sets (:class:`~tlessbot_ros.core.common.SkippedFrames`)."""
        stamps = [header_stamp_ns(msg.data) for msg in views[self._cameras[0]].values()
                  if isinstance(msg, RawMessage)]
        if stamps:
            self._skipped.add(max(stamps))

    @property
    def frame_period_s(self) -> float | None:
        """The period of the complete frames' stamps, seconds (None: not known yet)."""
        period_ns = self._skipped.period_ns
        return None if period_ns is None else period_ns / 1e9

    @property
    def unread_estimate(self) -> int:
        """Frames between the complete frames formed here that never formed: left unread
        while the gate was closed, lost on the way, or never complete (an estimate from the
        stamps' gaps)."""
        return self._skipped.count

    @property
    def dropped(self) -> int:
        """Messages and camera sets discarded because their partners never came in time, or
        their timeline ended (a time jump), and complete frames read after a pause that were
        older than the newest (:attr:`superseded`)."""
        return self._dropped_before + self._paired_dropped() + self.stale + self.superseded

    @property
    def gated(self) -> bool:
        """Whether a gate pauses the subscriptions."""
        return self._is_open is not None

    @property
    def stale(self) -> int:
        """Messages of a timeline that ended (after a time jump), dropped."""
        return self._stale_before + self._gate.stale

    def _paired_dropped(self) -> int:
        return self._across.dropped + sum(s.dropped for s in self._per_camera.values())
