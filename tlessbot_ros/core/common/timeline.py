"""Stream timelines: stamps that jump (a bag replayed in a loop without restamping goes back to
its first stamp; a camera's clock can step) are noticed by :class:`StampJumps`, and a
:class:`TimelineGate` in front of the synchronisers (:mod:`.sync`) empties their queues at a
jump, so no item of the old timeline is ever paired with one of the new, and drops the old
timeline's stragglers that arrive after the jump. Pure: no clock is read."""
from __future__ import annotations

from collections.abc import Hashable, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Generic, Literal, TypeVar

if TYPE_CHECKING:
    from tlessbot_ros.core.common.sync import StampSynchroniser

Item = TypeVar('Item')

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
                candidate = self._candidate.get(stream)
                if candidate is None or not self._in_line(candidate[1], stamp_ns):
                    first, seen = stamp_ns, 0   # a new candidate timeline
                else:
                    first, _, seen = candidate
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

    def __init__(self, jumps: StampJumps, synchronisers: Sequence[StampSynchroniser[Any]]) -> None:
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


__all__ = ['IN_ORDER', 'JUMP', 'STALE', 'StampJumps', 'TimelineGate', 'Verdict']
