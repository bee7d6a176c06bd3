"""SpareCpu: a frame's work is split only while the host has idle cores."""
from __future__ import annotations

import math

import pytest

from tlessbot_ros.parallel.spare_cpu import (
    SpareCpu,
    SpareCpuParams,
    read_cpu_counters,
    read_process_cpu_s,
)


class _Host:
    """Counters of a host whose cores are idle for a given share of each step."""

    def __init__(self, cores: int):
        self.cores, self.idle, self.total, self.now = cores, 0, 0, 0.0

    def run(self, seconds: float, idle_cores: float, ticks_per_s: int = 10_000) -> None:
        self.now += seconds
        self.idle += round(idle_cores * seconds * ticks_per_s)
        self.total += round(self.cores * seconds * ticks_per_s)

    def counters(self):
        return self.idle, self.total


def _spare(host: _Host, **params) -> SpareCpu:
    return SpareCpu(SpareCpuParams(**params), counters=host.counters, cores=host.cores,
                    clock=lambda: host.now)


def test_idle_cores_are_measured_between_readings_a_window_apart():
    host = _Host(cores=2)
    spare = _spare(host, window_s=0.5)
    assert spare.cores() == math.inf            # one reading: nothing known yet
    host.run(1.0, idle_cores=1.5)
    assert spare.cores() == pytest.approx(1.5)
    host.run(0.2, idle_cores=0.0)               # within the window: the last figure stands
    assert spare.cores() == pytest.approx(1.5)
    host.run(0.4, idle_cores=0.0)               # 0.6 s since the last reading, all busy
    assert spare.cores() == pytest.approx(0.0)


class _Stage:
    """A stage on a host: ``own`` is the stage's CPU time so far, seconds."""

    def __init__(self, host: _Host):
        self.host, self.own = host, 0.0

    def work(self, spare: SpareCpu, seconds: float, *, own_cores: float,
             others_cores: float) -> bool:
        """One frame's work that uses ``own_cores`` of the stage and ``others_cores`` of the
        rest of the host; returns whether the frame was split."""
        with spare.work() as split:
            self.own += own_cores * seconds
            self.host.run(seconds, idle_cores=self.host.cores - own_cores - others_cores)
        return split


def _stage_spare(host: _Host, stage: _Stage, **params) -> SpareCpu:
    return SpareCpu(SpareCpuParams(**params), counters=host.counters, cores=host.cores,
                    clock=lambda: host.now, own_cpu_s=lambda: stage.own)


def test_a_busy_host_keeps_the_frame_whole_and_an_idle_one_splits_it():
    host = _Host(cores=2)
    stage = _Stage(host)
    spare = _stage_spare(host, stage, min_spare_cores=0.5, window_s=0.5)
    # no figure yet: split as configured (the stage then uses 1.5 cores)
    assert stage.work(spare, 0.6, own_cores=1.5, others_cores=0.0)
    assert spare.cores_beside_work() == pytest.approx(1.0)   # its own second thread is not
    # another process on the host takes 1.3 cores while the stage works: whole frames
    assert stage.work(spare, 0.6, own_cores=0.7, others_cores=1.3)
    assert spare.cores_beside_work() == pytest.approx(-0.3)  # it did not even get a core
    assert not stage.work(spare, 0.6, own_cores=1.0, others_cores=0.3)
    assert spare.cores_beside_work() == pytest.approx(0.7)
    assert stage.work(spare, 0.6, own_cores=1.5, others_cores=0.3)
    assert (spare.splits, spare.kept_whole) == (3, 1)
    always = _stage_spare(host, stage, min_spare_cores=0.0)
    host.run(1.0, idle_cores=0.0)
    assert always.allows_split() and always.allows_split()


def test_only_the_stages_own_work_counts_not_the_time_between_its_frames():
    """One frame in flight: the other stages keep the host busy between this stage's frames,
    but a core is free while it works. The host's idle cores over the wall-clock time hide
    that core; the figure beside the stage's work shows it."""
    host = _Host(cores=2)
    stage = _Stage(host)
    spare = _stage_spare(host, stage, min_spare_cores=0.5, window_s=0.5)
    spare.cores()
    for _ in range(20):
        stage.work(spare, 0.05, own_cores=1.0, others_cores=0.3)   # this stage's frame
        host.run(0.1, idle_cores=0.2)                               # the other stages' work
    assert spare.cores() == pytest.approx((0.7 * 0.05 + 0.2 * 0.1) / 0.15)
    assert spare.cores() < 0.5   # the whole-time reading would keep the frame whole
    assert spare.cores_beside_work() == pytest.approx(0.7)
    assert spare.allows_split()


def test_an_idle_host_splits_even_when_another_stage_overlapped_the_work():
    """Frames that come slower than the graph works: the host is mostly idle, but the work of
    the previous frame's later stage overlapped this stage's. Idle cores over the wall-clock
    time are enough to split (else the frame, kept whole, overlaps the next ever more)."""
    host = _Host(cores=2)
    stage = _Stage(host)
    spare = _stage_spare(host, stage, min_spare_cores=0.5, window_s=0.5)
    for _ in range(6):
        stage.work(spare, 0.1, own_cores=1.0, others_cores=1.0)   # beside the work: 0 free
        host.run(0.3, idle_cores=2.0)                               # then nothing runs
    assert spare.cores_beside_work() == pytest.approx(0.0)
    assert spare.cores() >= 0.5 and spare.allows_split()


def test_work_spans_are_summed_until_a_window_is_measured():
    host = _Host(cores=2)
    stage = _Stage(host)
    spare = _stage_spare(host, stage, window_s=0.5)
    for _ in range(4):   # 0.4 s of work: not yet a figure
        stage.work(spare, 0.1, own_cores=1.0, others_cores=1.0)
    assert spare.cores_beside_work() == math.inf
    stage.work(spare, 0.1, own_cores=1.0, others_cores=1.0)
    assert spare.cores_beside_work() == pytest.approx(0.0)
    with spare.work(split_wanted=False) as split:   # not wanted: not split, not counted
        assert not split
    assert (spare.splits, spare.kept_whole) == (5, 0)


def test_unreadable_counters_leave_the_split_as_configured(tmp_path):
    assert read_cpu_counters(tmp_path / 'missing') is None
    (tmp_path / 'stat').write_text('intr 1 2 3\n')
    assert read_cpu_counters(tmp_path / 'stat') is None
    spare = SpareCpu(SpareCpuParams(min_spare_cores=1.0), counters=lambda: None, cores=2)
    assert spare.allows_split() and spare.cores() == math.inf
    for _ in range(3):
        with spare.work() as split:
            assert split
    assert spare.cores_beside_work() == math.inf


def test_the_kernels_counters_are_read():
    counters = read_cpu_counters()
    if counters is None:
        pytest.skip('no /proc/stat here')
    idle, total = counters
    assert 0 <= idle <= total and total > 0


def test_a_processes_cpu_time_is_read(tmp_path):
    import os
    import subprocess
    import sys

    if read_process_cpu_s(os.getpid()) is None:
        pytest.skip('no /proc/PID/stat here')
    # a child that burns 0.3 s of CPU, then waits for its stdin to close
    child = subprocess.Popen(
        [sys.executable, '-c', 'import sys, time\nt = time.process_time()\n'
         'while time.process_time() - t < 0.3: pass\nprint("done", flush=True)\n'
         'sys.stdin.read()'], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == 'done'
        assert read_process_cpu_s(child.pid) >= 0.25
    finally:
        child.stdin.close()
        child.wait(timeout=30)
    # a process with a space and a parenthesis in its name, 0.25 s of user time
    (tmp_path / '42').mkdir()
    (tmp_path / '42' / 'stat').write_text(
        '42 (a (b) c) R 1 1 1 0 -1 4194304 10 0 0 0 20 5 0 0 20 0 1 0 100 0 0\n')
    assert read_process_cpu_s(42, proc=tmp_path) == pytest.approx(25 / os.sysconf('SC_CLK_TCK'))
    assert read_process_cpu_s(43, proc=tmp_path) is None
    assert read_process_cpu_s(os.getpid()) >= 0.0


@pytest.mark.parametrize('field, value', [('min_spare_cores', -1.0),
                                          ('min_spare_cores', float('nan')),
                                          ('window_s', 0.0)])
def test_bad_params_are_refused(field, value):
    with pytest.raises(ValueError, match=field):
        SpareCpuParams(**{field: value})
