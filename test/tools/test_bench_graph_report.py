"""bench graph's report: where a posed frame's latency goes, and the replay's loop period."""
from __future__ import annotations

from types import SimpleNamespace

import pytest


def test_hop_latencies_split_each_posed_frame():
    from tlessbot_ros.tools.commands.bench.graph import hop_latencies
    from tlessbot_ros.tools.support.graph_run import GraphRunResult, ReceivedPose

    ms = 1_000_000
    result = GraphRunResult()
    for stamp in (1000 * ms, 2000 * ms):
        result.stage_arrivals.setdefault('localiser', {})[stamp] = stamp + 40 * ms
        result.stage_arrivals.setdefault('classifier', {})[stamp] = stamp + 70 * ms
        # two parts: the first pose counts for the last hop
        result.poses += [ReceivedPose(stamp, 5, None, 'f', stamp + 130 * ms),
                         ReceivedPose(stamp, 6, None, 'f', stamp + 120 * ms)]
    result.stage_arrivals['localiser'][3000 * ms] = 3040 * ms   # never posed: not counted
    hops = dict(hop_latencies(result))
    assert hops == {'stamp -> localiser labels': '40.0 / 40.0 ms',
                    'labels -> classifier classes': '30.0 / 30.0 ms',
                    'classes -> first pose': '50.0 / 50.0 ms'}
    assert hop_latencies(GraphRunResult()) == []


@pytest.mark.parametrize('times, expected', [
    ([0, 100, 100, 200, 300], 400),   # span 300 + one 100 gap: the next pass starts on time
    ([5], 0),
])
def test_a_looped_replay_waits_one_frame_interval_between_passes(times, expected):
    from tlessbot_ros.tools.support.replay import _loop_period_ns

    assert _loop_period_ns([SimpleNamespace(log_time_ns=t) for t in times]) == expected


def test_a_nodes_memory_and_cpu_include_its_worker_processes():
    import os
    import subprocess
    import sys
    import time

    from tlessbot_ros.tools.support.proc_stats import cpu_seconds, process_tree, rss_mb

    alone_mb = rss_mb(os.getpid())
    child = subprocess.Popen([sys.executable, '-c', 'x = bytearray(300 * 2**20)\n'
                              'x[::4096] = b"1" * len(x[::4096])\nimport time\ntime.sleep(30)'])
    try:
        deadline = time.monotonic() + 20
        while rss_mb(child.pid) < 300 and time.monotonic() < deadline:
            time.sleep(0.1)
        assert child.pid in process_tree(os.getpid())
        assert rss_mb(os.getpid()) - alone_mb > 250
        assert cpu_seconds(os.getpid()) > cpu_seconds(os.getpid(), descendants=False)
    finally:
        child.kill()
        child.wait()


def test_ratio_rows_compare_the_graph_with_its_stages_alone():
    from tlessbot_ros.tools.commands.bench.graph import ratio_rows
    from tlessbot_ros.tools.support.graph_run import GraphRunResult

    alone = {'localiser': {'median_ms': 30.0, 'cpu_ms_per_frame': 40.0},
             'classifier': {'median_ms': 10.0, 'cpu_ms_per_frame': 10.0},
             'pose_estimator': {'median_ms': 50.0, 'cpu_ms_per_frame': 50.0}}
    result = GraphRunResult(cpu_s={'localiser': 6.0, 'classifier': 2.0, 'pose_estimator': 10.0,
                                   'replay and monitor': 5.0},
                            diagnostics={'pose_estimator': {'frames': '100'}})
    rows = dict(ratio_rows(alone, p95_ms=117.0, duration_s=10.0, result=result, cores=2))
    assert rows['p95 latency / sum of the stages alone'] == '1.30'
    # 10 frames/s processed against 20 for the slowest stage (50 ms) alone
    assert rows['frames processed per s / (1 / slowest stage alone)'].endswith('= 0.50')
    # 18 CPU s over 100 frames (the replay and monitor is no node), against 100 ms own
    assert rows["CPU of the three nodes per processed frame / the stages' own CPU per frame"] \
        == '180.0 / 100.0 ms = 1.80'
    # two cores less half a core for the replay and monitor, at 100 ms a frame: 15 frames/s,
    # 0.75 x the slowest stage's 20
    ceiling = [value for name, value in rows.items() if name.startswith('ceiling')]
    assert ceiling == ['(2 - 0.50 - 0.00) cores / 100.0 ms = 15.00 / 20.00 = 0.75']
    # the host busy all the time (2 cores) while the graph took 1.2 and the replay and
    # monitor 0.3 of a core: something else (a hog) took 0.5
    result.cpu_s.update(localiser=3.0, classifier=2.0, pose_estimator=7.0, **{
        'replay and monitor': 3.0})
    result.host_ticks = ([0] * 10, [100, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    rows = dict(ratio_rows(alone, p95_ms=117.0, duration_s=10.0, result=result, cores=2))
    ceiling = [value for name, value in rows.items() if name.startswith('ceiling')]
    assert ceiling == ['(2 - 0.30 - 0.50) cores / 100.0 ms = 12.00 / 20.00 = 0.60']
    # time the hypervisor stole is not the graph's either: a tenth of 2 cores idle, a tenth
    # stolen, so 1.8 cores not idle, 1.5 of them the graph's and the replay's
    result.host_ticks = ([0] * 10, [80, 0, 0, 10, 0, 0, 0, 10, 0, 0])
    rows = dict(ratio_rows(alone, p95_ms=117.0, duration_s=10.0, result=result, cores=2))
    ceiling = [value for name, value in rows.items() if name.startswith('ceiling')]
    assert ceiling == ['(2 - 0.30 - 0.30) cores / 100.0 ms = 14.00 / 20.00 = 0.70']


def test_window_table_reports_each_window_and_the_trends():
    from tlessbot_ros.tools.commands.bench.graph import window_table
    from tlessbot_ros.tools.support.graph_run import GraphRunResult, ReceivedPose

    start = 10**18
    result = GraphRunResult(replay_start_ns=start)
    for second in range(120):            # 1 Hz samples over two 60 s windows
        result.sample_times_s.append(float(second))
        result.rss_mb_samples.setdefault('pose_estimator', []).append(900.0 + second / 60.0)
        result.fd_samples.setdefault('pose_estimator', []).append(40 if second < 60 else 41)
        result.thread_samples.setdefault('pose_estimator', []).append(12)
    for frame in range(10):              # frames posed 80 ms (window 0) and 120 ms (window 1)
        sent = start + int((frame * 12 + 1) * 1e9)
        delay_ms = 80 if frame < 5 else 120
        result.poses.append(ReceivedPose(sent, 5, None, 'f', sent + delay_ms * 1_000_000))
    table = window_table(result, 60.0)
    rows = [line for line in table.splitlines() if line.startswith('| 0-1') or
            line.startswith('| 1-2') or line.startswith('| pose_estimator')]
    assert rows[0] == '| 0-1 | 5 | 80.0 / 80.0 | 901 / 40 / 12 |'
    assert rows[1] == '| 1-2 | 5 | 120.0 / 120.0 | 902 / 41 / 12 |'
    assert rows[2] == '| pose_estimator | +1.00 | 41-41 | 12-12 |'


def test_the_report_shows_each_stages_split_and_the_hosts_idle_and_stolen_cpu():
    from tlessbot_ros.tools.commands.bench.graph import host_rows, split_rows

    rows = split_rows({'localiser': {'frames_split': '30', 'frames_kept_whole': '10',
                                     'cores_free_beside_work': '0.62'},
                       'pose_estimator': {'frames_split': '1093', 'frames_kept_whole': '7'},
                       'classifier': {'frames': '40'}})
    assert rows == [('localiser: frames split over a second core',
                     '30 of 40; cores free beside its work lately 0.62'),
                    ('pose_estimator: frames split over a second core',
                     '1093 of 1100; cores free beside its work lately ?')]
    # user nice system idle iowait irq softirq steal
    start = [100, 0, 10, 500, 0, 0, 0, 0]
    end = [400, 0, 60, 950, 50, 0, 0, 150]   # 1000 ticks: 500 idle (incl. iowait), 150 stolen
    assert host_rows((start, end)) == [('host while replaying: idle / stolen by the hypervisor',
                                        '50.0 % / 15.0 % of its CPU time')]
    assert host_rows((None, end)) == [] and host_rows((end, end)) == []


def test_diagnostics_show_counts_in_full_and_measures_to_three_digits():
    import numpy as np

    from tlessbot_ros.nodes.stage import _stat_text

    assert _stat_text(1093) == '1093' and _stat_text(np.int64(12345)) == '12345'
    assert _stat_text(True) == '1'
    assert _stat_text(12.3456) == '12.3' and _stat_text(float('inf')) == 'inf'
