"""Bounded stamp synchronisation of several message streams (message_filters' job, in pure
Python so it can be unit-tested and needs no ROS).

A :class:`StampSynchroniser` holds at most ``queue_size`` items per stream. When an item
arrives, it looks in every other stream for the item nearest in stamp; if all lie within
``slop_ns`` of it, the set is emitted and every item older than the set is dropped (counted in
:attr:`dropped`). Old frames are dropped, never queued without bound.

A slop wider than the frame period (two free-running cameras, or a stage's output waiting for
its inputs) would otherwise pair an item with the *previous* frame of a stream whose current
frame is merely late. So a partner older than the arriving item is not taken while that
stream's next item, expected one median period after its newest, would match clearly better;
the set forms when that item arrives (or the arriving item is dropped once newer sets form).
"""
from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

Item = TypeVar('Item')


@dataclass(frozen=True)
class SyncParams:
    """Synchronisation thresholds shared by the nodes.

    Attributes:
        slop_s: largest stamp difference within one camera's colour / depth / camera_info set.
            realsense-ros stamps aligned depth with the colour frame's stamp, so a small slop
            suffices.
        queue_size: items kept per stream while waiting for partners; it must cover the
            upstream latency (a pose estimator holds depth until the classes of the same frame
            arrive): 30 is one second at 30 fps.
        max_age_s: largest stamp difference between the top and the side camera sets that are
            fused into one two-view frame.
        max_rate_hz: most two-view frames processed per second (wall clock); a frame that
            completes sooner after the last one processed is dropped and counted (0 = no
            limit). On a small machine a stage that runs ahead (the localiser, the cheapest)
            takes the CPU the later stages need, and every frame's latency grows.
        worker_thread: process frames on a worker thread while the subscriptions keep
            feeding the synchroniser. A frame that completes while the worker is busy waits as
            the single pending frame; a newer one replaces it (the older is dropped and
            counted), so a slow stage works on the newest frame and never queues. Without the
            worker, frames are processed inside the subscription callback and the DDS history
            (``input_depth``) overflows meanwhile: a later stage then loses the camera frames
            it must pair with its upstream results and drops whole frames.
        max_message_mb: largest input message taken, MiB (0 = no limit); a larger one is
            counted as malformed and never queued (a 4K colour image is 24 MiB: thirty of them
            waiting for partners would hold 0.7 GiB per topic). The D415's largest stream,
            1920x1080 rgb8, is 5.9 MiB.
    """

    slop_s: float = 0.010
    queue_size: int = 30
    max_age_s: float = 0.050
    max_rate_hz: float = 0.0
    worker_thread: bool = True
    max_message_mb: float = 8.0

    def __post_init__(self) -> None:
        for name in ('slop_s', 'max_age_s', 'max_rate_hz', 'max_message_mb'):
            if not getattr(self, name) >= 0:   # NaN too
                raise ValueError(f'{name} must be >= 0, got {getattr(self, name)}')
        if self.queue_size < 1:
            raise ValueError(f'queue_size must be >= 1 (items kept per stream), got '
                             f'{self.queue_size}')


class StampSynchroniser(Generic[Item]):
    """Pairs items of named streams by stamp (nanoseconds); bounded memory."""

    def __init__(self, streams: Sequence[str], *, slop_ns: int, queue_size: int) -> None:
        if len(set(streams)) != len(streams) or not streams:
            raise ValueError(f'streams must be distinct names, got {list(streams)}')
        if queue_size < 1 or slop_ns < 0:
            raise ValueError('queue_size must be >= 1 and slop_ns >= 0')
        self.streams = tuple(streams)
        self.slop_ns = int(slop_ns)
        self._queues: dict[str, deque[tuple[int, Item]]] = {
            name: deque() for name in self.streams}
        self._queue_size = queue_size
        self._recent: dict[str, deque[int]] = {name: deque(maxlen=9) for name in self.streams}
        self.dropped = 0
        self.emitted = 0

    def add(self, stream: str, stamp_ns: int, item: Item) -> dict[str, Item] | None:
        """Queue ``item``; returns ``{stream: item}`` when a complete set forms, else None."""
        queue = self._queues.get(stream)
        if queue is None:
            raise KeyError(f'unknown stream {stream!r}; expected one of {self.streams}')
        if len(queue) >= self._queue_size:
            del queue[self._eviction_index(stream)]
            self.dropped += 1
        queue.append((int(stamp_ns), item))
        self._recent[stream].append(int(stamp_ns))
        chosen: dict[str, tuple[int, Item]] = {stream: (int(stamp_ns), item)}
        for other in self.streams:
            if other == stream:
                continue
            nearest = min(self._queues[other], key=lambda entry: abs(entry[0] - stamp_ns),
                          default=None)
            if nearest is None or abs(nearest[0] - stamp_ns) > self.slop_ns:
                return None
            if self._better_partner_due(other, nearest[0], int(stamp_ns)):
                return None
            chosen[other] = nearest
        for name, (stamp, _) in chosen.items():
            queue = self._queues[name]
            while queue and queue[0][0] <= stamp:
                entry = queue.popleft()
                if entry[0] != stamp:
                    self.dropped += 1
        self.emitted += 1
        return {name: entry[1] for name, entry in chosen.items()}

    def _eviction_index(self, stream: str) -> int:
        """Which item of a full queue to drop: the oldest one that no other stream has a
        partner for within the slop, else the oldest. Items of a frame wait in several streams
        for the last one (a later stage's input waits for its upstream result); a flood of
        items that will never pair (garbage, a stray publisher) then evicts itself instead of
        them."""
        others = [self._queues[name] for name in self.streams if name != stream]
        for index, (stamp, _) in enumerate(self._queues[stream]):
            if not any(abs(other_stamp - stamp) <= self.slop_ns
                       for other in others for other_stamp, _ in other):
                return index
        return 0

    def _better_partner_due(self, stream: str, partner_ns: int, pivot_ns: int) -> bool:
        """True when ``stream``'s next item, expected one median period after its newest,
        would lie less than half as far from the pivot as the partner it has now."""
        if partner_ns >= pivot_ns:
            return False   # items arrive in stamp order: later ones would only be farther
        stamps = list(self._recent[stream])
        steps = [b - a for a, b in zip(stamps, stamps[1:]) if b > a]
        if not steps:
            return False   # no period known yet: take what is there
        expected = stamps[-1] + sorted(steps)[len(steps) // 2]
        return abs(expected - pivot_ns) < (pivot_ns - partner_ns) / 2

    def pending(self) -> dict[str, int]:
        """Items waiting per stream."""
        return {name: len(queue) for name, queue in self._queues.items()}
