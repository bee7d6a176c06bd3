"""How a stage node admits the complete frames its inputs pair: the one place to read and change.

Every stage caps its rate (:class:`RateCap`, ``sync.max_rate_hz``). The graph's entrance (the
localiser) also applies backpressure (:class:`Entrance`, ``admission.*``): it takes a frame
only while fewer than ``admission.max_in_flight`` frames it took are still unfinished
downstream (the policy: :class:`~tlessbot_ros.core.common.InFlightFrames`), so frames are
dropped at the entrance instead of queueing in the later stages. The newest refused frame waits
for the next free slot (``admission.hold_newest``). While the entrance is full, the inputs are
not read at all (``admission.pause_inputs``; :meth:`Entrance.is_open` is the inputs' gate,
:class:`~tlessbot_ros.nodes.inputs.TwoViewInputs`): their messages wait in DDS and the outcome
that frees a slot reads them and takes the newest complete frame. Without a last stage that
reports outcomes, every frame is taken.

Threads: frames come on the executor's thread; outcomes of this stage come from its frame
thread, those of later stages on the executor's. The entrance serialises them with one lock.
Nothing here needs a ROS graph: the owner hands in the callables that reach the node.
"""
from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from typing import Any

from tlessbot_ros.conversions.outcomes import DONE
from tlessbot_ros.core.common import AdmissionParams, InFlightFrames
from tlessbot_ros.nodes.inputs import Views, newest_stamp_ns


class RateCap:
    """``sync.max_rate_hz``: a complete frame that comes within ``1 / max_rate_hz`` of the last
    frame taken is dropped and counted (frames released at a time jump never are)."""

    def __init__(self) -> None:
        self.dropped = 0
        self._last_start = -math.inf

    def allows(self, max_rate_hz: float, now: float, *, held: bool = False) -> bool:
        """Whether a frame that completes at ``now`` (s) may be taken; counts a refusal."""
        if not held and max_rate_hz > 0 and now - self._last_start < 1.0 / max_rate_hz:
            self.dropped += 1
            return False
        return True

    def taken(self, now: float) -> None:
        """A frame was taken at ``now``: the next one is timed from here."""
        self._last_start = now


class Entrance:
    """Backpressure at the graph's entrance (only the localiser holds one).

    Args:
        params: ``admission.*``.
        last_stage_reports: whether the last stage (the pose estimator) publishes outcomes
            now; without it every frame is taken.
        middle_reports: whether every stage between the entrance and the last publishes its
            outcomes (``admission.pipeline_behind_last_stage``).
        take: takes an admitted frame (hands it to the frame worker).
        reopen: reads what waited in the paused inputs, ``reopen(keep_newest)``.
        threaded: the stage has a frame thread; without one a frame waiting here is taken by
            the next frame to arrive, not by the outcome that freed the slot.
        spare_cores, camera_period_s, stages: for ``pipeline_min_spare_cores``
            (:class:`~tlessbot_ros.core.common.InFlightFrames`).
    """

    def __init__(self, params: AdmissionParams, *, last_stage_reports: Callable[[], bool],
                 middle_reports: Callable[[], bool], take: Callable[[Views], None],
                 reopen: Callable[[bool], None], threaded: bool = True,
                 spare_cores: Callable[[], float] = lambda: math.inf,
                 camera_period_s: Callable[[], float | None] = lambda: None,
                 stages: int = 3) -> None:
        self.in_flight = InFlightFrames(params, spare_cores=spare_cores,
                                        camera_period_s=camera_period_s, stages=stages,
                                        middle_reports=middle_reports)
        self._last_stage_reports = last_stage_reports
        self._take, self._reopen, self._threaded = take, reopen, threaded
        self._lock = threading.Lock()
        self._was_open = True
        self.dropped = 0   # frames refused for good (never entered the graph: not reported)

    def admit(self, views: Views, *, held: bool = False) -> bool:
        """Whether to take a complete frame now: only while fewer than
        ``admission.max_in_flight`` are unfinished downstream (``held`` frames, released at a
        time jump, always: they are few, once). A refused frame waits for the next free slot
        (``hold_newest``), replacing an older one; an older frame still waiting when a slot is
        free is taken first."""
        if not self._last_stage_reports():
            return True
        stamp_ns = newest_stamp_ns(views)
        if stamp_ns is None:
            return True
        now = time.monotonic()
        with self._lock:
            older = self.in_flight.take_waiting(now)
            admitted = self.in_flight.try_admit(stamp_ns, now, force=held)
            dropped = None if admitted else self.in_flight.hold(stamp_ns, views)
        if older is not None:
            self._take(older)
        if dropped is not None:
            self.dropped += 1
        return admitted

    def is_open(self) -> bool:
        """The inputs' gate (executor thread, every turn): while the entrance is full
        (``pause_inputs``) nothing the inputs bring could be taken, so they are not read. An
        entrance that opens without an outcome (a frame expired, cores came free) reads what
        waited, newest first."""
        if not self.in_flight.params.pause_inputs or not self._last_stage_reports():
            is_open = True
        else:
            with self._lock:
                is_open = self.in_flight.has_room(time.monotonic())
        if is_open and not self._was_open:
            self._reopen(self.in_flight.params.hold_newest)
        self._was_open = is_open
        return is_open

    def finished_here(self, stamp_ns: int, outcome: str) -> None:
        """This stage finished frame ``stamp_ns``: one it dropped or failed never reaches the
        later stages, so its trip ends here."""
        if outcome != DONE:
            with self._lock:
                self.in_flight.finish(stamp_ns, time.monotonic(), completed=False)
            self._take_waiting()

    def finished_downstream(self, stamp_ns: int, outcome: str, *, last_stage: bool) -> None:
        """A later stage reported frame ``stamp_ns``: the last stage's outcome, or any that is
        not 'done', ends its trip; a middle stage's 'done' puts it with the last stage, and a
        frame may follow it in."""
        if last_stage or outcome != DONE:
            with self._lock:
                self.in_flight.finish(stamp_ns, time.monotonic(),
                                      completed=last_stage and outcome == DONE)
            self._take_waiting()
            return
        with self._lock:
            room = self.in_flight.reached_last_stage(stamp_ns) and \
                self.in_flight.has_room(time.monotonic())
        if room:
            self._take_waiting()

    def time_jumped(self) -> None:
        """Stamps jumped: the open frames and the waiting one belong to the old timeline."""
        with self._lock:
            self.in_flight.clear()
            self._drop_waiting()

    def set_params(self, params: AdmissionParams) -> None:
        """New ``admission.*``; more room, or no more pausing: read what waited."""
        with self._lock:
            self.in_flight.params = params
            if not params.hold_newest:
                self._drop_waiting()
        self._reopen(params.hold_newest)

    def stats(self) -> dict[str, Any]:
        """The entrance's figures for /diagnostics."""
        with self._lock:
            return {'in_flight': self.in_flight.open_count,
                    'entrance_refused': self.in_flight.refused,
                    'entrance_waited': self.in_flight.released,
                    'in_flight_expired': self.in_flight.expired}

    def _take_waiting(self) -> None:
        """A slot may have freed: take the frame waiting here, if any (only with a frame
        thread: without one a frame is processed inside the callback that freed the slot, and
        the next frame to arrive takes the waiting one instead), and read what waited unread
        in the inputs while the entrance was full."""
        if self._threaded:
            with self._lock:
                views = self.in_flight.take_waiting(time.monotonic())
            if views is not None:
                self._take(views)
        self._reopen(self.in_flight.params.hold_newest)

    def _drop_waiting(self) -> None:
        """Give up the frame waiting here (caller holds the lock)."""
        if self.in_flight.drop_waiting() is not None:
            self.dropped += 1
