"""Split a frame's work over a second thread or process only while the host has cores to spare.

The localiser can segment its two views in two threads and the pose estimator can fit parts in
a worker process beside its own thread. That shortens a frame when the other cores are idle
(a graph at 2 frames/s, lock-step replays). In a graph at the camera's rate they are not: the
entrance admits frames until the stages keep every core busy, and the second thread or process
then only adds contention, hand-offs and a copy of the work's inputs (paired 60 s runs at
30 frames/s on 2 cores, docs/bench/backpressure.md: with both off, 1.29-1.39 x the frames
processed and 0.74-0.80 x the p95 latency on a host busy with other work; with this gate
against always splitting, 1.02-1.13 x and 0.87-0.97 x on a quiet one). :class:`SpareCpu`
reads how much of the host was idle lately, so a stage can decide per frame.

The figure comes from the kernel's CPU time counters (``/proc/stat``, Linux): idle and iowait
time over all cores, in cores, averaged over the time since the previous reading (at least
``window_s``). Time of processes run with a raised nice value counts as busy: work the
scheduler would preempt for us is not told apart from ours. Where the counters cannot be read
(another OS) the host is taken to have cores to spare, which keeps the split as configured.
"""
from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

# /proc/stat "cpu" line: user nice system idle iowait irq softirq steal (guest time is already
# inside user and nice)
_COUNTED_FIELDS = 8
_IDLE_FIELDS = (3, 4)   # idle, iowait


@dataclass(frozen=True)
class SpareCpuParams:
    """When a stage splits one frame's work.

    Attributes:
        min_spare_cores: split a frame's work (the localiser's two views in two threads, the
            pose estimator's parts over its worker processes) only while at least this many of
            the host's cores were idle over the last ``window_s``; otherwise do it in one
            thread, which costs less CPU per frame. 0: always split (as configured by
            ``parallel_views`` and ``workers.count``).
        window_s: shortest time over which the idle share is measured, seconds.
    """

    min_spare_cores: float = 0.5
    window_s: float = 0.5

    def __post_init__(self) -> None:
        if not self.min_spare_cores >= 0:   # NaN too
            raise ValueError(f'min_spare_cores must be >= 0, got {self.min_spare_cores}')
        if not self.window_s > 0:
            raise ValueError(f'window_s must be > 0 s, got {self.window_s}')


def read_cpu_counters(path: str | Path = '/proc/stat') -> tuple[int, int] | None:
    """(idle, total) CPU time over all cores, in clock ticks, or None where unreadable."""
    try:
        with open(path, encoding='ascii') as stat:
            fields = stat.readline().split()
    except OSError:
        return None
    if len(fields) < _COUNTED_FIELDS + 1 or fields[0] != 'cpu':
        return None
    try:
        ticks = [int(v) for v in fields[1:_COUNTED_FIELDS + 1]]
    except ValueError:
        return None
    return sum(ticks[i] for i in _IDLE_FIELDS), sum(ticks)


class SpareCpu:
    """Idle cores of the host, measured between readings at least ``window_s`` apart.

    Example:
        >>> spare = SpareCpu(SpareCpuParams(min_spare_cores=0.5))
        >>> if spare.allows_split(): ...   # use the second thread for this frame

    Thread-safe; a reading costs one small file read at most every ``window_s``.
    """

    def __init__(self, params: SpareCpuParams = SpareCpuParams(), *,
                 counters: Callable[[], tuple[int, int] | None] = read_cpu_counters,
                 cores: int | None = None, clock: Callable[[], float] = time.monotonic
                 ) -> None:
        self.params = params
        self._counters, self._clock = counters, clock
        self._cores = cores or os.cpu_count() or 1
        self._lock = threading.Lock()
        self._last: tuple[float, tuple[int, int]] | None = None
        self._spare = math.inf   # until two readings exist: no information, split as set
        self.splits = 0          # frames split / not, for /diagnostics
        self.kept_whole = 0

    def cores(self) -> float:
        """Cores idle on average since the previous reading (inf before the first two, or
        where the counters cannot be read)."""
        with self._lock:
            now = self._clock()
            if self._last is not None and now - self._last[0] < self.params.window_s:
                return self._spare
            counters = self._counters()
            if counters is None:
                return self._spare
            if self._last is not None:
                idle = counters[0] - self._last[1][0]
                total = counters[1] - self._last[1][1]
                if total > 0:
                    self._spare = self._cores * idle / total
            self._last = (now, counters)
            return self._spare

    def allows_split(self) -> bool:
        """Whether this frame's work may be split (and count the answer)."""
        split = self.params.min_spare_cores <= 0 or self.cores() >= self.params.min_spare_cores
        if split:
            self.splits += 1
        else:
            self.kept_whole += 1
        return split
