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
camera's clock can step) are noticed by :class:`StampJumps`: a synchroniser given one empties
its queues at a jump, so no item of the old timeline is ever paired with one of the new, and
drops the old timeline's stragglers that arrive after the jump.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Generic, Literal, TypeVar

Item = TypeVar('Item')


EXECUTORS = ('events', 'single_threaded')   # SyncParams.executor


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
        jump_back_s: a topic whose stamp goes back by more than this (seconds) has jumped to a
            new timeline: a bag replayed in a loop without ``--restamp`` (the demo bag goes
            back 0.33 s), a camera clock stepped back. One publisher's stamps never go back,
            so this only needs to clear a driver's small timestamp corrections. The node
            empties its synchronisation queues, counts the jump (``time_jumps`` on
            /diagnostics) and goes on with the new timeline.
        jump_forward_s: a topic whose stamp leaps forward by more than this (seconds) has
            jumped too (a clock stepped forward, a camera back after a long gap); handled as
            a jump back.
        live_stamp_window_s: a frame whose newest stamp lies within this many seconds of the
            node's clock was stamped by that clock (a live camera on a synchronised host):
            /diagnostics reports its input age. Stamps further away come from another clock
            (a bag replayed without ``--restamp``, a camera whose clock is not synchronised):
            their age would measure the clocks' offset, not a delay, so only that offset
            (``stamp_offset_s``) is reported.
        jump_confirmations: how many more items of a topic must follow, in line, the first one
            that stepped back off its timeline before the step counts as a time jump on that
            topic's word alone; one is enough when another topic's held items carry exactly the
            same stamps (whole frames jumped: one camera stamps its colour, depth and
            camera_info alike). Until then the items are held (at most this many per topic);
            once the jump is confirmed they are paired as if it had been declared at once. A
            stray message with an absurd stamp (another publisher on a camera topic, a driver
            glitch) is then dropped instead of emptying every queue (under garbage at 100 Hz
            on every input, ``tlessbot bench fuzz``, 0 answered none of the good frames).
            0: every step back beyond ``jump_back_s`` is a jump at once. That is what a stage
            behind the localiser's relay needs (:meth:`behind_relay`): it sees only the frames
            the localiser admitted, whose timeline the localiser has confirmed, and may see a
            single frame of a short loop per pass, which could never confirm a jump. A leap
            forward is never held: a camera that paused, or frames sent on demand, go through
            at once.
        max_message_mb: largest input message taken, MiB (0 = no limit); a larger one is
            counted as malformed and never queued (a 4K colour image is 24 MiB: thirty of them
            waiting for partners would hold 0.7 GiB per topic). The D415's largest stream,
            1920x1080 rgb8, is 5.9 MiB.
        executor: how the node's thread takes messages, timers and services: 'events'
            (rclpy's EventsExecutor: it waits in C++ and calls each callback as its event
            comes) or 'single_threaded' (rclpy's SingleThreadedExecutor, which rebuilds its
            wait set in Python at every turn). In the graph at 30 fps the single-threaded
            executor's own Python took 7-10 ms of CPU per processed frame in each stage node,
            beside the frame's work and under the same interpreter lock; the events executor
            took about 4 (docs/bench/backpressure.md). The localiser's default is
            'single_threaded': while its entrance is full it leaves the camera messages unread
            in DDS, which only an executor that asks the callback groups allows; the events
            executor would hand it every message of every camera topic. Paired 30 fps runs:
            1.04-1.06 x the frames answered with 'events' in all three stages, 1.10-1.23 x
            with the localiser on 'single_threaded', at the same or lower latency. The nodes
            spin it with ``spin_once`` in a loop, never its ``spin()``, which in rclpy 7.1
            fires no timer and stalls holding the interpreter lock when another thread
            creates an entity (scripts/events_executor_check.py).
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


Verdict = Literal['in order', 'jump', 'stale']
IN_ORDER: Verdict = 'in order'
JUMP: Verdict = 'jump'
STALE: Verdict = 'stale'


class StampJumps:
    """Notices stamps that jump, stream by stream (nanoseconds; pure, no clock is read).

    A stream is one publisher's topic (any hashable name): its stamps only go forward. An item
    whose stamp lies more than ``back_ns`` before its stream's previous one, or more than
    ``forward_ns`` after it, starts a new timeline (:data:`JUMP`): everything queued by stamp
    must be forgotten. The other streams jumped too (one clock stamps them all), but their
    items sent before the jump may still be on their way: until a stream's first item of the
    new timeline comes, an item that continues its old timeline is :data:`STALE` (drop it), at
    most ``stale_limit`` in a row (a stream whose clock did not jump joins the new timeline as
    it is).

    With ``confirmations`` > 0, a few items out of line are not yet a jump: a stray message
    (another publisher's, a corrupt stamp) would otherwise throw every queue away. Items that
    step back off a stream's timeline are held as a candidate timeline (:data:`STALE`, counted
    in :attr:`outliers`); the jump is declared when ``confirmations`` more items of the stream
    follow the candidate's first in line, or already when one does and another stream's
    candidate holds exactly the same two stamps (whole frames jumped: a looped bag's or a
    stepped clock's second frame confirms it, which matters for a later stage that sees only
    the few frames of a short loop its upstream admitted), and the candidate is forgotten when
    the stream's old timeline goes on. A :class:`TimelineGate` keeps the held items and passes
    them on once the jump is confirmed, so a real jump loses nothing. Items that leap forward
    go through (:data:`IN_ORDER`) while their leap is confirmed the same way
    (``SyncParams.jump_confirmations``).

    Attributes:
        count: jumps seen.
        last_jump_ns: signed size of the last jump (new stamp - the stream's previous; < 0 back).
        outliers: items off their stream's timeline that no next item confirmed (so far).
    """

    def __init__(self, *, back_ns: int, forward_ns: int, stale_limit: int = 30,
                 confirmations: int = 0) -> None:
        if back_ns <= 0 or forward_ns <= 0 or stale_limit < 0 or confirmations < 0:
            raise ValueError('back_ns and forward_ns must be > 0, stale_limit and '
                             'confirmations >= 0')
        self.confirmations = confirmations
        self.back_ns, self.forward_ns = int(back_ns), int(forward_ns)
        self.stale_limit = stale_limit
        self.count = 0
        self.last_jump_ns = 0
        self._target_ns = 0                 # the stamp the last jump went to
        self._last: dict[Hashable, int] = {}     # per stream: its newest stamp
        self._epoch: dict[Hashable, int] = {}    # per stream: the jump count its newest stamp saw
        self._stale: dict[Hashable, int] = {}    # per stream: stale items since the last jump
        # per stream: (first, newest stamp, items) of a timeline off the stream's, held
        self._candidate: dict[Hashable, tuple[int, int, int]] = {}
        self.outliers = 0

    def check(self, stream: Hashable, stamp_ns: int) -> Verdict:
        """Classify the next item of ``stream`` (and remember its stamp)."""
        stamp_ns = int(stamp_ns)
        last = self._last.get(stream)
        verdict = IN_ORDER
        if last is not None and self._epoch[stream] == self.count:
            if not self._in_line(last, stamp_ns):
                first, newest, seen = self._candidate.get(stream, (None, None, 0))
                if newest is None or not self._in_line(newest, stamp_ns):
                    first, seen = stamp_ns, 0   # a new candidate timeline
                seen += 1
                forward = stamp_ns > last
                if seen <= self.confirmations and not (
                        seen >= 2 and self._agreed(stream, first, stamp_ns)):
                    # held until enough items follow it, or another stream agrees
                    self._candidate[stream] = (first, stamp_ns, seen)
                    if forward:   # a pause, not a step back: nothing queued is in the way
                        return IN_ORDER
                    self.outliers += 1
                    return STALE
                self._candidate.pop(stream, None)
                if not forward:
                    self.outliers -= seen - 1   # they were the new timeline's first items
                self.count += 1
                self.last_jump_ns, self._target_ns = first - last, first
                self._stale.clear()
                self._candidate.clear()   # the other streams' candidates: see adopt()
                if forward:   # streams that went through the leap are on the new timeline
                    for other, other_last in self._last.items():
                        if other_last >= first - self.back_ns:
                            self._epoch[other] = self.count
                verdict = JUMP
            else:
                self._candidate.pop(stream, None)   # the old timeline goes on: stray items
        elif last is not None and not self._joins_new_timeline(stamp_ns, last) and \
                self._stale.get(stream, 0) < self.stale_limit:
            self._stale[stream] = self._stale.get(stream, 0) + 1
            self._last[stream] = stamp_ns
            return STALE
        self._last[stream], self._epoch[stream] = stamp_ns, self.count
        return verdict

    def reading_order(self, waiting: Mapping[Hashable, Sequence[tuple[int, Item]]]
                      ) -> list[tuple[Hashable, int, Item]]:
        """The order in which to check items that waited unread in several streams (a paused
        entrance reads them all at once): as if they had come one by one. Each stream's items
        keep the order they came in; across streams they go by their stamps on the streams'
        timelines. An item off its stream's timeline (a stray, or a jump's new timeline) comes
        right after the item before it in its stream, as it did when it came: sorted by its
        own stamp, a run of strays that came one at a time between good items would come in a
        row and confirm a jump to their timeline.

        Args:
            waiting: stream -> ``[(stamp_ns, item)]`` in arrival order.
        Returns:
            ``[(stream, stamp_ns, item)]``, every item once (pass each to :meth:`check`, or
            :meth:`TimelineGate.admit`, in this order). Nothing is changed here.
        """
        entries = []
        for index, (stream, items) in enumerate(waiting.items()):
            timeline = key = self._last.get(stream)   # the stamp its timeline is at
            for position, (stamp, item) in enumerate(items):
                stamp = int(stamp)
                if timeline is None or self._in_line(timeline, stamp):
                    timeline = stamp
                    key = stamp if key is None else max(key, stamp)   # the stream's order kept
                entries.append((key, index, position, stream, stamp, item))
        entries.sort(key=lambda entry: entry[:3])
        return [(stream, stamp, item) for *_, stream, stamp, item in entries]

    @property
    def jump_target_ns(self) -> int:
        """The stamp the last jump went to (the new timeline's first)."""
        return self._target_ns

    def candidate(self, stream: Hashable) -> tuple[int, int] | None:
        """The timeline ``stream`` holds as a candidate, if any: (its first stamp, the number
        of items it has had)."""
        candidate = self._candidate.get(stream)
        return None if candidate is None else (candidate[0], candidate[2])

    def adopt(self, stream: Hashable, stamps_ns: Sequence[int]) -> bool:
        """After a jump another stream confirmed: whether the items ``stream`` held as its own
        candidate (``stamps_ns``, in order) belong to the new timeline; if so they join it, as
        if they had come after the jump, and no longer count as outliers."""
        last = self._last.get(stream)
        if not stamps_ns or last is None or not self._joins_new_timeline(stamps_ns[0], last):
            return False
        self._last[stream], self._epoch[stream] = int(stamps_ns[-1]), self.count
        self.outliers -= len(stamps_ns)
        return True

    def _agreed(self, stream: Hashable, first_ns: int, newest_ns: int) -> bool:
        """Whether another stream holds a candidate timeline with exactly the same first and
        newest stamps as this one's: two frames jumped on every topic, as one camera stamps
        its colour, depth and camera_info alike. A stray stamp on one topic never repeats on
        another (a second publisher stamping several topics alike, twice in line, is a second
        timeline, and taken for one)."""
        return any(other != stream and candidate[0] == first_ns and candidate[1] == newest_ns
                   for other, candidate in self._candidate.items())

    def _in_line(self, previous_ns: int, stamp_ns: int) -> bool:
        """Whether ``stamp_ns`` may follow ``previous_ns`` on one timeline."""
        return -self.back_ns <= stamp_ns - previous_ns <= self.forward_ns

    def _joins_new_timeline(self, stamp_ns: int, last_ns: int) -> bool:
        """Whether an item of a stream not yet seen since the jump belongs to the new timeline:
        nearer the stamp the jump went to than its stream's last, or (after a jump back) not
        after its stream's last (an old timeline only goes forward)."""
        if self.last_jump_ns < 0 and stamp_ns <= last_ns:
            return True
        return abs(stamp_ns - self._target_ns) <= abs(stamp_ns - last_ns)


class TimelineGate(Generic[Item]):
    """Lets items through by their stream's timeline (:class:`StampJumps`), in front of the
    synchronisers that pair them: a stale item is dropped (counted in :attr:`stale`), and a
    jump back empties every synchroniser (:meth:`StampSynchroniser.reset`), since nothing
    queued can pair with the new timeline; a jump forward drops what is queued before it.

    The items a candidate timeline holds while its jump waits for confirmation
    (``StampJumps(confirmations > 0)``) are kept here, at most ``confirmations`` per stream,
    and released in stamp order once the jump is confirmed: a bag looped without ``--restamp``
    then loses no frame to the confirmation, and a stray stamp still empties nothing. Items of
    a candidate the old timeline outlives are dropped (counted in :attr:`stale`).
    """

    def __init__(self, jumps: StampJumps, synchronisers: Sequence[StampSynchroniser]) -> None:
        self.jumps = jumps
        self.synchronisers = tuple(synchronisers)
        self.stale = 0
        # per stream: the held items of its candidate timeline, (stamp_ns, item), oldest first
        self._held: dict[Hashable, list[tuple[int, Item]]] = {}

    def admit(self, stream: Hashable, stamp_ns: int, item: Item
              ) -> tuple[Verdict, list[tuple[Hashable, int, Item]]]:
        """The verdict on the next item of ``stream``, its effects applied, and the items to
        pass on to the synchronisers now, ``[(stream, stamp_ns, item)]`` in stamp order: the
        item itself when in order; nothing when stale or held; after a confirmed jump the
        held items of every stream that joins the new timeline, then this one."""
        stamp_ns = int(stamp_ns)
        verdict = self.jumps.check(stream, stamp_ns)
        if verdict != JUMP:
            candidate = self.jumps.candidate(stream)
            held = self._held.pop(stream, [])
            # a backward candidate holds every item it has had, this one last; anything else
            # held began a candidate that ended (its old timeline went on) or restarted
            if verdict == STALE and candidate is not None and held and \
                    held[0][0] == candidate[0] and len(held) == candidate[1] - 1:
                self._held[stream] = held + [(stamp_ns, item)]
                return verdict, []
            self.stale += len(held)
            if verdict == STALE and candidate is not None and candidate == (stamp_ns, 1):
                self._held[stream] = [(stamp_ns, item)]
                return verdict, []
            if verdict == STALE:
                self.stale += 1
                return verdict, []
            return verdict, [(stream, stamp_ns, item)]
        if self.jumps.last_jump_ns < 0:
            for synchroniser in self.synchronisers:
                synchroniser.reset()
        else:
            for synchroniser in self.synchronisers:
                synchroniser.drop_before(self.jumps.jump_target_ns)
        released = [(stream, stamp, held_item)
                    for stamp, held_item in self._held.pop(stream, [])]
        for other, items in self._held.items():
            if self.jumps.adopt(other, [stamp for stamp, _ in items]):
                released += [(other, stamp, held_item) for stamp, held_item in items]
            else:
                self.stale += len(items)
        self._held.clear()
        released.sort(key=lambda entry: entry[1])
        return verdict, released + [(stream, stamp_ns, item)]


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
