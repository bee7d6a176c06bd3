"""Admission by backpressure: the graph's entrance starts a frame only when the stages after it
can take one.

A fixed admission rate (``sync.max_rate_hz``) is tuned to one host: too low wastes a fast
machine, too high overloads a slow one, and then every admitted frame waits inside the graph
behind the previous ones. Here the entrance (the localiser) counts the frames it has admitted
whose outcome the last stage has not yet reported, and admits a new frame only while fewer than
``max_in_flight`` are open. Frames are therefore dropped at the entrance and never queue
inside, at any camera rate and on any host; with ``max_in_flight`` 2 the entrance segments
frame N+1 while the later stages work on frame N (pipelining).

A refused frame is not dropped at once: the newest one waits at the entrance (one slot,
``hold_newest``) and is taken as soon as a slot frees, unless a newer frame replaces it first.
At a camera rate the graph can follow on average, a frame that arrives while a slow one is
still being fitted is then answered a little later instead of lost
(docs/bench/free-running.md); at a rate it cannot follow, all but the newest frame are still
dropped here, and the one that waits is at most one camera period old when it is taken.

A second frame in flight pays only where a core is free for it: on two cores, with the camera
drivers or a replay taking a third of one, the localiser segmenting frame N+1 while the pose
estimator fits frame N made every stage run at about half its speed alone, so that one frame
in flight had the lower latency for nearly as many frames (docs/bench/backpressure.md). So a
frame beyond the first is admitted only while ``pipeline_min_spare_cores`` of the host were
idle lately, or while the camera's frames come no faster than the graph's average stage works
(a bag at its recorded 2 frames/s on a busy host: each frame is worth answering, and a refused
one would be lost; docs/bench/code-figures.md). On a host with cores to spare the graph
pipelines at any rate; on a busy or small one at 30 fps it does not.

An outcome may never come (the last stage restarted, a message was lost, the pairing dropped
the frame): an open frame expires after ``expiry_factor`` times the slowest recent
admission-to-outcome time, and never sooner than ``min_expiry_s``, so the timeout follows the
host's speed instead of being tuned to one.
"""
from __future__ import annotations

import math
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class AdmissionParams:
    """Backpressure at the graph's entrance (the localiser's ``admission.*`` parameters; the
    measurements behind the defaults: docs/bench/parameter-notes.md).

    Attributes:
        max_in_flight: frames admitted and not yet finished by the last stage (>= 0); another is
            dropped at the entrance. 0: no backpressure.
        expiry_factor: an open frame is given up after this many times the slowest recent
            admission-to-outcome time (>= 1).
        min_expiry_s: the expiry is never shorter than this, s (> 0).
        hold_newest: a frame refused while the graph is full waits at the entrance (the newest
            only); False: it is dropped.
        pause_inputs: while the graph is full, leave camera messages unread in DDS and take the
            newest frame when a slot frees.
        pipeline_min_spare_cores: a second frame in flight only while this many host cores were
            idle lately, cores (>= 0; 0: always).
        pipeline_behind_last_stage: a second frame in flight only once every open frame has passed
            the middle stage (the classifier).

    With ``max_in_flight`` 2 the localiser works on the next frame while the later stages
    finish the previous one. ``pipeline_min_spare_cores`` also admits a second frame while the
    camera period is at least the graph's average stage time (the median time a frame takes
    over the stages it passes: pipelined, the graph answers every frame); where the cores are
    not free, a second frame in flight only slows every stage. With
    ``pipeline_behind_last_stage`` the new frame's first stages run while the last stage works
    on the previous one, and it reaches the last stage about when that is free instead of
    waiting inside behind it. ``pause_inputs`` keeps the newest ``input_depth`` messages of
    each topic in DDS instead of taking every one only to refuse it.
    """

    max_in_flight: int = 2
    expiry_factor: float = 3.0
    min_expiry_s: float = 1.0
    hold_newest: bool = True
    pause_inputs: bool = True
    pipeline_min_spare_cores: float = 1.0
    pipeline_behind_last_stage: bool = True

    def __post_init__(self) -> None:
        if self.max_in_flight < 0:
            raise ValueError(f'max_in_flight must be >= 0 (0: no backpressure), got '
                             f'{self.max_in_flight}')
        if self.expiry_factor < 1.0:
            raise ValueError(f'expiry_factor must be >= 1, got {self.expiry_factor}')
        if self.min_expiry_s <= 0:
            raise ValueError(f'min_expiry_s must be > 0 seconds, got {self.min_expiry_s}')
        if not self.pipeline_min_spare_cores >= 0:   # NaN too
            raise ValueError(f'pipeline_min_spare_cores must be >= 0, got '
                             f'{self.pipeline_min_spare_cores}')


class InFlightFrames:
    """The frames admitted at the entrance and not yet finished downstream, by stamp (ns).

    Times are the caller's monotonic clock in seconds. Not thread-safe: the owner serialises
    calls (the node's executor thread and worker thread share one lock). For
    ``pipeline_min_spare_cores``, ``spare_cores`` returns how many of the host's cores were idle
    lately (without it the host is taken to have cores to spare), ``camera_period_s`` the
    period of the frames coming in (None: not known yet), and ``stages`` how many stages a
    frame passes between its admission and its outcome. For ``pipeline_behind_last_stage``,
    ``middle_reports`` says whether the stages before the last report the frames they finish
    (:meth:`reached_last_stage`; without them that gate is off).
    """

    def __init__(self, params: AdmissionParams = AdmissionParams(), *,
                 spare_cores: Callable[[], float] = lambda: math.inf,
                 camera_period_s: Callable[[], float | None] = lambda: None,
                 stages: int = 3, middle_reports: Callable[[], bool] = lambda: False) -> None:
        self.params = params
        self._spare_cores, self._camera_period_s = spare_cores, camera_period_s
        self._stages = stages
        self._middle_reports = middle_reports
        self._open: OrderedDict[int, float] = OrderedDict()   # stamp_ns -> admitted at (s)
        self._at_last_stage: set[int] = set()   # open frames the stages before the last finished
        self._recent_s: deque[float] = deque(maxlen=20)
        self.admitted = 0
        self.finished = 0
        self.expired = 0
        self.refused = 0
        self.released = 0     # refused frames that waited, then were admitted
        self._waiting: tuple[int, Any] | None = None   # (stamp_ns, frame) held at the entrance

    @property
    def enabled(self) -> bool:
        return self.params.max_in_flight > 0

    @property
    def open_count(self) -> int:
        return len(self._open)

    def expiry_s(self) -> float:
        """How long an open frame waits for its outcome before it is given up."""
        slowest = max(self._recent_s, default=0.0)
        return max(self.params.min_expiry_s, self.params.expiry_factor * slowest)

    def try_admit(self, stamp_ns: int, now_s: float, *, force: bool = False) -> bool:
        """Admit the frame ``stamp_ns`` if fewer than ``max_in_flight`` are open (after
        expiring the overdue ones), or anyway when ``force``d; count a refusal otherwise."""
        if not self.enabled:
            return True
        if not self._has_room(now_s) and not force:   # expires overdue frames first
            self.refused += 1
            return False
        self._open[int(stamp_ns)] = now_s
        self.admitted += 1
        return True

    @property
    def waiting_stamp_ns(self) -> int | None:
        """The stamp of the frame waiting at the entrance (None: none waits)."""
        return None if self._waiting is None else self._waiting[0]

    def hold(self, stamp_ns: int, frame: Any) -> Any | None:
        """Keep a refused ``frame`` waiting for a slot (``hold_newest``). Returns the frame
        this drops: the older one that was waiting, ``frame`` itself when holding is off, or
        None."""
        if not self.params.hold_newest:
            return frame
        dropped = None if self._waiting is None else self._waiting[1]
        self._waiting = (int(stamp_ns), frame)
        return dropped

    def take_waiting(self, now_s: float) -> Any | None:
        """Admit and return the waiting frame if a slot is free now (None otherwise)."""
        if self._waiting is None or not self._has_room(now_s):
            return None
        stamp_ns, frame = self._waiting
        self._waiting = None
        self._open[stamp_ns] = now_s
        self.admitted += 1
        self.released += 1
        return frame

    def drop_waiting(self) -> Any | None:
        """Give up the waiting frame (time jumped, holding turned off); returns it."""
        frame = None if self._waiting is None else self._waiting[1]
        self._waiting = None
        return frame

    def finish(self, stamp_ns: int, now_s: float, *, completed: bool = True) -> bool:
        """The outcome of frame ``stamp_ns`` is known: it leaves the open set. ``completed``
        frames (processed by the last stage, not dropped on the way) teach the expiry how long
        a frame takes. False when the frame was not open (another entrance's, or expired)."""
        admitted_at = self._open.pop(int(stamp_ns), None)
        self._at_last_stage.discard(int(stamp_ns))
        if admitted_at is None:
            return False
        self.finished += 1
        if completed:
            self._recent_s.append(max(0.0, now_s - admitted_at))
        return True

    def clear(self) -> None:
        """Forget every open frame (time jumped; the stages downstream restarted). A frame
        waiting at the entrance stays: :meth:`drop_waiting` gives it up."""
        self._open.clear()
        self._at_last_stage.clear()

    def reached_last_stage(self, stamp_ns: int) -> bool:
        """The stages before the last finished open frame ``stamp_ns`` (it is with the last
        stage now). False when the frame is not open."""
        if int(stamp_ns) not in self._open:
            return False
        self._at_last_stage.add(int(stamp_ns))
        return True

    def has_room(self, now_s: float) -> bool:
        """Whether a frame would be admitted now (after expiring the overdue ones)."""
        return not self.enabled or self._has_room(now_s)

    def _has_room(self, now_s: float) -> bool:
        self._expire(now_s)
        if len(self._open) >= self.params.max_in_flight:
            return False
        if not self._open:
            return True
        if self.params.pipeline_behind_last_stage and \
                any(stamp not in self._at_last_stage for stamp in self._open) and \
                self._middle_reports():   # last: the owner may ask the middleware
            return False
        if self.params.pipeline_min_spare_cores <= 0:
            return True
        return self._spare_cores() >= self.params.pipeline_min_spare_cores or \
            self._camera_within_reach()

    def _camera_within_reach(self) -> bool:
        """Whether frames come no faster than the graph's average stage works: the median
        recent admission-to-outcome time over the ``stages`` a frame passes (unknown before
        the first finishes: False). A pipelined graph then keeps up and every frame can be
        answered, while one refused would be lost: a slow frame at 2 frames/s on a busy host
        must not cost the next."""
        period = self._camera_period_s()
        if period is None or not self._recent_s:
            return False
        recent = sorted(self._recent_s)
        return period * self._stages >= recent[len(recent) // 2]

    def _expire(self, now_s: float) -> None:
        limit = self.expiry_s()
        while self._open:
            stamp, admitted_at = next(iter(self._open.items()))
            if now_s - admitted_at <= limit:
                break
            del self._open[stamp]
            self._at_last_stage.discard(stamp)
            self.expired += 1
