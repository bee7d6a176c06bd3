"""What a stage node reports on ``/diagnostics``, at 1 Hz: its counters and figures.

Frames processed, failures, frames dropped (by synchronisation, ``sync.max_rate_hz``, a busy
worker, the entrance), the processing latency, readiness, and:

- ``input_age_ms_p50`` / ``_p95``: how old a frame (its newest stamp) is by the node's clock when
  its processing starts. Only frames stamped by this clock count: a stamp within
  ``sync.live_stamp_window_s`` of it.
- ``stamp_offset_s``, ``other_clock_frames``: frames whose stamps lie further from the node's
  clock come from another clock (a bag replayed without ``--restamp``, a host whose clock is not
  synchronised); their "age" would be the clocks' offset, so it is reported apart.
- ``time_jumps``, ``last_time_jump_s``: how often the input stamps jumped and the last jump's
  size (s, < 0 back).

:class:`StageStatus` holds the figures; :meth:`StageStatus.report` turns them into one
status (level, message, values) without touching ROS.
"""
from __future__ import annotations

import os
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from tlessbot_ros.nodes.diagnostics import ERROR, OK, WARN

# A stage's own warning ('' for none; it makes an OK status WARN) and values (a snapshot).
Extra = Callable[[], tuple[str, dict[str, str]]]


class StageStatus:
    """A stage node's counters, recent figures and readiness, for /diagnostics."""

    def __init__(self) -> None:
        self.created = time.monotonic()
        self.ready = threading.Event()
        self.ready_after_s: float | None = None   # from construction to ready
        self.warm_up_s: float | None = None
        self.frames = 0
        self.failures = 0
        self.busy_dropped = 0   # complete frames replaced by a newer one while the worker ran
        self.last_error = ''
        self.latencies_ms: deque[float] = deque(maxlen=100)
        self.input_ages_ms: deque[float] = deque(maxlen=100)
        self.other_clock_frames = 0   # frames stamped by another clock (input age not measured)
        self.stamp_offset_s: float | None = None
        self.stats: dict[str, float] = {}   # the last frame's figures (record_stats)
        self.extras: list[Extra] = []

    def set_ready(self, warm_up_s: float) -> None:
        """The stage is warmed up and subscribed."""
        self.warm_up_s, self.ready_after_s = warm_up_s, time.monotonic() - self.created
        self.ready.set()

    def record_input_age(self, offset_ns: int, live_window_s: float) -> None:
        """A frame's age (``offset_ns``: the node's clock minus its newest stamp), if it was
        stamped by the node's clock (within ``live_window_s``); else the clocks' offset."""
        if abs(offset_ns) <= live_window_s * 1e9:
            self.input_ages_ms.append(offset_ns / 1e6)
        else:
            self.other_clock_frames += 1
            self.stamp_offset_s = offset_ns / 1e9

    def time_jumped(self) -> None:
        """The input stamps jumped: ages start again. The clocks' offset is kept until the next
        frame measures it: /diagnostics published in between would otherwise lose it."""
        self.input_ages_ms.clear()

    def clock_values(self, jumps: Any) -> dict[str, str | int]:
        """/diagnostics keys on the input stamps' clock: other clocks, time jumps
        (``jumps``: the inputs' :class:`~tlessbot_ros.core.common.StampJumps`, or None)."""
        values: dict[str, str | int] = {}
        if self.other_clock_frames:
            values['other_clock_frames'] = self.other_clock_frames
        if self.stamp_offset_s is not None:
            values['stamp_offset_s'] = f'{self.stamp_offset_s:.3f}'
        values['time_jumps'] = jumps.count if jumps else 0
        if jumps and jumps.count:
            values['last_time_jump_s'] = f'{jumps.last_jump_ns / 1e9:.3f}'
        return values

    def report(self, *, inputs: Any, rate_dropped: int, entrance_dropped: int,
               parameters: Any) -> tuple[Any, str, dict[str, Any]]:
        """(level, message, values) of the status now. ``inputs``: the node's
        :class:`~tlessbot_ros.nodes.inputs.TwoViewInputs` (None before it subscribed);
        ``rate_dropped``: frames the :class:`~tlessbot_ros.nodes.admission.RateCap` skipped;
        ``parameters``: its :class:`~tlessbot_ros.nodes.parameters.LiveParameters`."""
        dropped = (inputs.dropped if inputs else 0) + rate_dropped + \
            self.busy_dropped + entrance_dropped
        level = OK if not self.failures else (ERROR if self.frames == 0 else WARN)
        readiness = {'ready': 'true', 'ready_after_s': f'{self.ready_after_s:.2f}',
                     'warm_up_s': f'{self.warm_up_s:.2f}'} if self.ready.is_set() else \
            {'ready': 'false', 'starting_s': f'{time.monotonic() - self.created:.1f}'}
        if not self.ready.is_set():
            level = ERROR if self.last_error else WARN
        values = {**readiness, 'pid': os.getpid(), 'frames': self.frames,
                  'failures': self.failures, 'dropped': dropped,
                  **_percentiles('latency_ms', self.latencies_ms),
                  **_percentiles('input_age_ms', self.input_ages_ms),
                  **self.clock_values(inputs.jumps if inputs else None),
                  'zero_stamps': inputs.zero_stamps if inputs else 0,
                  'malformed': inputs.malformed if inputs else 0,
                  **({'unread_frames_est': inputs.unread_estimate}
                     if inputs and inputs.gated else {}),
                  **{k: stat_text(v) for k, v in self.stats.items()}}
        if parameters.changes:
            values.update(parameter_changes=parameters.changes,
                          last_parameter_change=parameters.last_change)
        if self.last_error:
            values['last_error'] = self.last_error
        message = 'ok' if level == OK else (self.last_error or 'starting')
        for extra in self.extras:
            warning, extra_values = extra()
            values.update(extra_values)
            if warning and level == OK:
                level, message = WARN, warning
        return level, message, values


def _percentiles(name: str, values: deque[float]) -> dict[str, str]:
    """``{name_p50, name_p95}`` of recent values, formatted (empty before the first)."""
    if not values:
        return {}
    p50, p95 = np.percentile(np.asarray(values), [50, 95])
    return {f'{name}_p50': f'{p50:.1f}', f'{name}_p95': f'{p95:.1f}'}


def stat_text(value: float) -> str:
    """A frame figure for /diagnostics: counts in full (a running count above 999 must not
    become '1.1e+03'), measures to 3 significant digits."""
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return f'{value:.3g}'
