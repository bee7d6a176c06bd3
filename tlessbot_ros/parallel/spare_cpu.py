"""Split a frame's work over a second thread or process only while the host has cores to spare.

The localiser can segment its two views in two threads and the pose estimator can fit parts in
a worker process beside its own thread. That shortens a frame when the other cores are idle
(a graph at 2 frames/s, lock-step replays, a graph whose entrance runs one frame at a time). In
a graph whose stages all work at once they are not: the second thread or process then only
adds contention, hand-offs and a copy of the work's inputs (docs/bench/backpressure.md).
:class:`SpareCpu` measures, per stage, whether a core was free while that stage worked, so a
stage can decide per frame.

The figure comes from the kernel's CPU time counters (``/proc/stat``, Linux), read when a
frame's work starts and when it ends, and from the stage's own CPU time over the same spans
(its process, all threads, and its worker processes). What the rest of the host used while the
stage worked is the host's busy time less the stage's own; the cores left beside the one the
stage's thread needs are the figure. Only the spans of the stage's own work count: a graph
whose other stages work between this stage's frames (one frame in flight) leaves a core free
*while this stage works*, and a reading over the whole wall-clock time would hide it (paired
runs, docs/bench/backpressure.md). Either reading lets a stage split: frames that come slower
than the graph works leave the host idle over the wall-clock time while a later stage of the
previous frame may overlap this stage's work, and a frame kept whole for it overlaps the next
one even more. Time of processes run with a raised nice value counts as busy: work the scheduler
would preempt for us is not told apart from ours. Where the counters cannot be read (another
OS) the host is taken to have cores to spare, which keeps the split as configured.
"""
from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

# /proc/stat "cpu" line: user nice system idle iowait irq softirq steal (guest time is already
# inside user and nice)
_COUNTED_FIELDS = 8
_IDLE_FIELDS = (3, 4)   # idle, iowait
# the unit of proc_pid_stat(5)'s CPU times
_CLOCK_TICKS_PER_S = os.sysconf('SC_CLK_TCK') if hasattr(os, 'sysconf') else 100


@dataclass(frozen=True)
class SpareCpuParams:
    """When a stage splits one frame's work.

    Attributes:
        min_spare_cores: split a frame's work (two views, parts over workers) only while this many
            cores were free lately (>= 0; 0: always).
        window_s: shortest span over which the free cores are measured, s (> 0).
    """

    min_spare_cores: float = 0.5
    window_s: float = 0.5

    def __post_init__(self) -> None:
        if not self.min_spare_cores >= 0:   # NaN too
            raise ValueError(f'min_spare_cores must be >= 0, got {self.min_spare_cores}')
        if not self.window_s > 0:
            raise ValueError(f'window_s must be > 0 s, got {self.window_s}')


def read_cpu_ticks(path: str | Path = '/proc/stat') -> list[int] | None:
    """CPU time over all cores so far, in clock ticks: user, nice, system, idle, iowait, irq,
    softirq, steal (time the hypervisor gave to other machines); None where unreadable."""
    try:
        with open(path, encoding='ascii') as stat:
            fields = stat.readline().split()
    except OSError:
        return None
    if len(fields) < _COUNTED_FIELDS + 1 or fields[0] != 'cpu':
        return None
    try:
        return [int(v) for v in fields[1:_COUNTED_FIELDS + 1]]
    except ValueError:
        return None


def read_cpu_counters(path: str | Path = '/proc/stat') -> tuple[int, int] | None:
    """(idle, total) CPU time over all cores, in clock ticks, or None where unreadable."""
    ticks = read_cpu_ticks(path)
    if ticks is None:
        return None
    return sum(ticks[i] for i in _IDLE_FIELDS), sum(ticks)


def read_process_cpu_s(pid: int, proc: str | Path = '/proc') -> float | None:
    """User + system CPU time of process ``pid`` (all its threads) so far, seconds, or None
    where it cannot be read (the process ended, another OS)."""
    try:
        text = Path(proc, str(pid), 'stat').read_text(encoding='ascii', errors='replace')
        # the command name in parentheses may hold spaces; utime and stime are fields 14
        # and 15 of proc_pid_stat(5), the 12th and 13th after it
        after_name = text[text.rindex(')') + 2:].split()
        return (int(after_name[11]) + int(after_name[12])) / _CLOCK_TICKS_PER_S
    except (OSError, ValueError, IndexError):
        return None


class SpareCpu:
    """Free cores of the host: beside a stage's own work (:meth:`work`, whether to split a
    frame), and overall (:meth:`cores`, idle cores between readings ``window_s`` apart).

    Example:
        >>> spare = SpareCpu(SpareCpuParams(min_spare_cores=0.5))
        >>> with spare.work() as split:   # measures the host while the frame is worked on
        ...     localise(views, in_two_threads=split)

    ``own_cpu_s`` gives the stage's own CPU time so far, seconds (default: this process, all
    threads; a stage with worker processes adds theirs). Thread-safe; a reading costs two small
    file reads.
    """

    def __init__(self, params: SpareCpuParams = SpareCpuParams(), *,
                 counters: Callable[[], tuple[int, int] | None] = read_cpu_counters,
                 own_cpu_s: Callable[[], float] = time.process_time,
                 cores: int | None = None, clock: Callable[[], float] = time.monotonic
                 ) -> None:
        self.params = params
        self.own_cpu_s = own_cpu_s
        self._counters, self._clock = counters, clock
        self._cores = cores or os.cpu_count() or 1
        self._lock = threading.Lock()
        self._last: tuple[float, tuple[int, int]] | None = None
        self._spare = math.inf   # until two readings exist: no information, split as set
        # the stage's work spans since the last figure: host idle and total ticks, own CPU
        # seconds, wall seconds
        self._work_sums = [0, 0, 0.0, 0.0]
        self._beside_work = math.inf   # until window_s of work is measured: split as set
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

    def cores_beside_work(self) -> float:
        """Cores that were free beside the stage's own thread while it worked, on average over
        its last ``window_s`` of work (inf until then, or where the counters cannot be read).
        Negative: the stage itself did not get a whole core."""
        with self._lock:
            return self._beside_work

    def allows_split(self) -> bool:
        """Whether this frame's work may be split (and count the answer)."""
        # Either reading suffices. Beside the work: one frame in flight leaves a core free while
        # this stage works although the other stages kept the host busy in between. Over the
        # wall-clock time: frames that come slower than the graph works leave the host idle,
        # and a frame kept whole there overlaps the next, which lowers the reading beside the
        # work in turn (at 5 fps that kept 2/3 of the frames whole in a run on a busy host).
        least, idle = self.params.min_spare_cores, self.cores()   # read on every frame
        split = least <= 0 or self.cores_beside_work() >= least or idle >= least
        if split:
            self.splits += 1
        else:
            self.kept_whole += 1
        return split

    def stats(self) -> dict[str, float]:
        """The split's figures for /diagnostics: frames split and kept whole, and the cores
        free beside the stage's work (inf: not measured yet)."""
        return {'frames_split': self.splits, 'frames_kept_whole': self.kept_whole,
                'cores_free_beside_work': round(self.cores_beside_work(), 2)}

    @contextmanager
    def work(self, split_wanted: bool = True) -> Iterator[bool]:
        """Measure the host while the ``with`` block does one frame's work; yields whether
        the work may be split (always False, and the frame not counted, when
        ``split_wanted`` is False)."""
        start = self._work_reading()
        try:
            yield split_wanted and self.allows_split()
        finally:
            end = self._work_reading()
            if start is not None and end is not None:
                self._add_work_span(start, end)

    def _work_reading(self) -> tuple[int, int, float, float] | None:
        counters = self._counters()
        if counters is None:
            return None
        return (*counters, self.own_cpu_s(), self._clock())

    def _add_work_span(self, start: tuple[int, int, float, float],
                       end: tuple[int, int, float, float]) -> None:
        with self._lock:
            sums = self._work_sums
            for k in range(4):
                sums[k] += end[k] - start[k]
            idle_ticks, total_ticks, own_s, wall_s = sums
            if wall_s < self.params.window_s or total_ticks <= 0:
                return
            idle_cores = self._cores * idle_ticks / total_ticks
            # free beside our thread = cores - 1 - (busy - own) = idle + own - 1
            self._beside_work = idle_cores + max(own_s, 0.0) / wall_s - 1.0
            self._work_sums = [0, 0, 0.0, 0.0]
