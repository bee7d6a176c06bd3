"""Bounded stamp synchronisation of several message streams (message_filters' job, in pure
Python so it can be unit-tested and needs no ROS).

A :class:`StampSynchroniser` holds at most ``queue_size`` items per stream. When an item
arrives, it looks in every other stream for the item nearest in stamp; if all lie within
``slop_ns`` of it, the set is emitted and every item older than the set is dropped (counted in
:attr:`dropped`). Old frames are dropped, never queued without bound.

A slop wider than the frame period (two free-running cameras, or a stage's output waiting for
its inputs) would otherwise pair an item with the *previous* frame of a stream whose current
frame is merely late. So a partner older than the arriving item is not taken while that
stream's next item, expected one period after its newest (:func:`stream_period_ns`), would
match clearly better; the set forms when that item arrives (or the arriving item is dropped
once newer sets form).

Stamps that jump (a bag replayed in a loop without restamping goes back to its first stamp; a
camera's clock can step) are handled in :mod:`.timeline`: a gate in front of the synchronisers
empties their queues at a jump, so no item of the old timeline is ever paired with one of the
new.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Generic, TypeVar

Item = TypeVar('Item')


EXECUTORS = ('events', 'single_threaded')   # SyncParams.executor


@dataclass(frozen=True)
class SyncParams:
    """Synchronisation thresholds shared by the nodes (why each default is what it is, with the
    measurements: docs/bench/parameter-notes.md).

    Attributes:
        slop_s: largest stamp difference within one camera's colour / depth / camera_info set, s
            (>= 0).
        queue_size: items kept per stream while waiting for partners (>= 1); must cover the
            upstream latency (30: one second at 30 fps).
        max_age_s: largest stamp difference between the top and side camera sets fused into one
            frame, s (>= 0).
        max_rate_hz: most two-view frames processed per second (wall clock), Hz (>= 0); a frame
            sooner is dropped. 0: no limit.
        worker_thread: process frames on a worker thread, the newest frame waiting (never a queue);
            False: in the subscription callback.
        jump_back_s: a topic whose stamp goes back by more than this, s (> 0), has jumped to a new
            timeline: the queues are emptied.
        jump_forward_s: a topic whose stamp leaps forward by more than this, s (> 0), has jumped
            too.
        live_stamp_window_s: stamps within this of the node's clock, s (> 0), are live:
            /diagnostics reports input age, else clock offset.
        jump_confirmations: items of a topic that must follow a step back, in line, before it
            counts as a jump (>= 0; 0: at once).
        max_message_mb: largest input message taken, MiB (>= 0; 0: no limit); a larger one counts
            as malformed.
        executor: how the node takes its callbacks: 'events' (rclpy's EventsExecutor) or
            'single_threaded' (SingleThreadedExecutor).
    """

    slop_s: float = 0.010
    queue_size: int = 30
    max_age_s: float = 0.050
    max_rate_hz: float = 0.0
    worker_thread: bool = True
    jump_back_s: float = 0.1
    jump_forward_s: float = 10.0
    live_stamp_window_s: float = 5.0
    jump_confirmations: int = 4
    max_message_mb: float = 8.0
    executor: str = 'events'

    def __post_init__(self) -> None:
        if self.executor not in EXECUTORS:
            raise ValueError(f'executor must be one of {list(EXECUTORS)}, got '
                             f'{self.executor!r}')
        for name in ('slop_s', 'max_age_s', 'max_rate_hz', 'max_message_mb'):
            if not getattr(self, name) >= 0:   # NaN too
                raise ValueError(f'{name} must be >= 0, got {getattr(self, name)}')
        if self.queue_size < 1:
            raise ValueError(f'queue_size must be >= 1 (items kept per stream), got '
                             f'{self.queue_size}')
        if self.jump_confirmations < 0:
            raise ValueError(f'jump_confirmations must be >= 0, got {self.jump_confirmations}')
        for name in ('jump_back_s', 'jump_forward_s', 'live_stamp_window_s'):
            if not getattr(self, name) > 0:
                raise ValueError(f'{name} must be > 0 s, got {getattr(self, name)}')

    def behind_relay(self) -> SyncParams:
        """These thresholds for a stage whose camera frames come from the localiser's relay
        (``input_source: localiser``): the localiser confirmed their timeline before it
        admitted them, so a step back there is a real jump and counts at once
        (``jump_confirmations`` 0; see its description)."""
        return replace(self, jump_confirmations=0)


class StampSynchroniser(Generic[Item]):
    """Pairs items of named streams by stamp (nanoseconds); bounded memory. A
    :class:`TimelineGate` in front of it empties it (:meth:`reset`) when stamps jump."""

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

    def reset(self) -> None:
        """Forget every queued item (counted as dropped) and the streams' periods: what is
        queued belongs to a timeline that ended."""
        self.dropped += sum(len(queue) for queue in self._queues.values())
        for name in self.streams:
            self._queues[name].clear()
            self._recent[name].clear()

    def drop_before(self, stamp_ns: int) -> None:
        """Forget the items more than the slop older than ``stamp_ns`` (counted as dropped),
        and the periods measured across it: after a leap forward in stamps, what waits from
        before the leap can pair with nothing that comes."""
        cutoff = int(stamp_ns) - self.slop_ns
        for name in self.streams:
            queue = self._queues[name]
            kept = [entry for entry in queue if entry[0] >= cutoff]
            self.dropped += len(queue) - len(kept)
            self._queues[name] = deque(kept)
            recent = self._recent[name]
            recent_kept = [stamp for stamp in recent if stamp >= cutoff]
            recent.clear()
            recent.extend(recent_kept)

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
        """True when ``stream``'s next item, expected one period after its newest, would lie
        less than half as far from the pivot as the partner it has now."""
        if partner_ns >= pivot_ns:
            return False   # items arrive in stamp order: later ones would only be farther
        stamps = list(self._recent[stream])
        period = stream_period_ns(stamps)
        if period is None:
            return False   # no period known yet: take what is there
        return abs(stamps[-1] + period - pivot_ns) < (pivot_ns - partner_ns) / 2

    def pending(self) -> dict[str, int]:
        """Items waiting per stream."""
        return {name: len(queue) for name, queue in self._queues.items()}


def stream_period_ns(stamps_ns: Sequence[int]) -> int | None:
    """A stream's period from its recent stamps (ns, in arrival order): the lower quartile of
    the steps between them, None before two distinct stamps.

    Not the median: a reader that skips frames (an entrance that leaves them unread while the
    graph is full, a best-effort subscription that loses some) sees steps of several periods,
    often as many as single ones; the smallest steps are the period. Not the minimum either: one
    stray stamp close to another would pass for it.
    """
    steps = sorted(b - a for a, b in zip(stamps_ns, stamps_ns[1:]) if b > a)
    return steps[len(steps) // 4] if steps else None


class SkippedFrames:
    """Estimates how many frames of a stream were never seen, from the gaps in the stamps
    that were (ns, in order): a step of k periods (:func:`stream_period_ns`) skipped k - 1.

    The steps in the recent window are counted with the period known now, so a gap seen
    before the stream's period was is counted right once it is; older steps keep the count
    they had when they left the window. A step back (a new timeline) starts the window again.
    """

    def __init__(self, window: int = 9) -> None:
        self._stamps: deque[int] = deque(maxlen=window)
        self._settled = 0

    def add(self, stamp_ns: int) -> None:
        stamps = self._stamps
        if stamps and stamp_ns <= stamps[-1]:
            self._settled = self.count
            stamps.clear()
        elif len(stamps) == stamps.maxlen:
            period = stream_period_ns(list(stamps))
            self._settled += self._skipped(stamps[1] - stamps[0], period)
        stamps.append(int(stamp_ns))

    @property
    def period_ns(self) -> int | None:
        """The stream's period (:func:`stream_period_ns` of the recent stamps)."""
        return stream_period_ns(list(self._stamps))

    @property
    def count(self) -> int:
        stamps = list(self._stamps)
        period = stream_period_ns(stamps)
        return self._settled + sum(self._skipped(b - a, period)
                                   for a, b in zip(stamps, stamps[1:]))

    @staticmethod
    def _skipped(step_ns: int, period_ns: int | None) -> int:
        return max(0, round(step_ns / period_ns) - 1) if period_ns else 0
