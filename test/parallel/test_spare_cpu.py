"""SpareCpu: a frame's work is split only while the host has idle cores."""
from __future__ import annotations

import math

import pytest

from tlessbot_ros.parallel.spare_cpu import SpareCpu, SpareCpuParams, read_cpu_counters


class _Host:
    """Counters of a host whose cores are idle for a given share of each step."""

    def __init__(self, cores: int):
        self.cores, self.idle, self.total, self.now = cores, 0, 0, 0.0

    def run(self, seconds: float, idle_cores: float, ticks_per_s: int = 100) -> None:
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


def test_a_busy_host_keeps_the_frame_whole_and_an_idle_one_splits_it():
    host = _Host(cores=2)
    spare = _spare(host, min_spare_cores=0.5, window_s=0.5)
    assert spare.allows_split()                 # no figure yet: split as configured
    host.run(1.0, idle_cores=0.2)
    assert not spare.allows_split()
    host.run(1.0, idle_cores=1.2)
    assert spare.allows_split()
    assert (spare.splits, spare.kept_whole) == (2, 1)
    always = _spare(host, min_spare_cores=0.0)
    host.run(1.0, idle_cores=0.0)
    assert always.allows_split() and always.allows_split()


def test_unreadable_counters_leave_the_split_as_configured(tmp_path):
    assert read_cpu_counters(tmp_path / 'missing') is None
    (tmp_path / 'stat').write_text('intr 1 2 3\n')
    assert read_cpu_counters(tmp_path / 'stat') is None
    spare = SpareCpu(SpareCpuParams(min_spare_cores=1.0), counters=lambda: None, cores=2)
    assert spare.allows_split() and spare.cores() == math.inf


def test_the_kernels_counters_are_read():
    counters = read_cpu_counters()
    if counters is None:
        pytest.skip('no /proc/stat here')
    idle, total = counters
    assert 0 <= idle <= total and total > 0


@pytest.mark.parametrize('field, value', [('min_spare_cores', -1.0),
                                          ('min_spare_cores', float('nan')),
                                          ('window_s', 0.0)])
def test_bad_params_are_refused(field, value):
    with pytest.raises(ValueError, match=field):
        SpareCpuParams(**{field: value})
