"""Graph latency: replay a bag at a frame rate through the three perception nodes (processes).

    tlessbot bench graph --fps 30 --duration 60

Stamps are shifted to now (replay --restamp), so latency is the time from a frame's source
stamp to the arrival of its PoseStamped here (p50, p95). A frame is dropped when no pose comes
back for its stamp. RSS and CPU of each node include its child processes (the pose estimator's
workers). RSS is sampled every second; the trend is a least-squares
slope in MiB per minute, over the whole run and over its second half (allocator pools and caches
fill during the first frames; a leak keeps its slope in the second half).

Before the graph it runs ``tlessbot bench nodes`` on the same bag (each stage's callbacks alone,
one process, no DDS) and prints the ratios that hold on any host, since both sides are measured
in the same run: p95 latency / the sum of the stages' medians alone; frames processed per
second / (1 / the slowest stage alone); the graph's CPU per processed frame / the stages' own;
and the host's ceiling on the second ratio (its cores at the stages' own CPU per frame).
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_TEMPLATES
from tlessbot_ros.io.bags import read_bag
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.support.defaults import DEFAULT_BAG
from tlessbot_ros.tools.support.graph_run import FRAME_TOPIC, MONITOR


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', default=str(DEFAULT_BAG))
    parser.add_argument('--fps', type=float, default=30.0, help='replayed frame rate')
    parser.add_argument('--duration', type=float, default=60.0, help='seconds of replay')
    parser.add_argument('--classifier', default=str(DEFAULT_CLASSIFIER))
    parser.add_argument('--templates', default=str(DEFAULT_TEMPLATES))
    parser.add_argument('--config', default=None)
    parser.add_argument('--out', default=None, help='write the Markdown table here')
    parser.add_argument('--window', type=float, default=300.0, metavar='S',
                        help='also print latency, frames, RSS, open files and threads per window '
                             'of this many seconds when the run holds two or more (a soak)')
    parser.add_argument('--no-stages-alone', dest='stages_alone', action='store_false',
                        help='skip the stages-alone run (bench nodes) and the ratios')


def bag_frame_interval_s(bag: str) -> float:
    """Median interval between the side colour frames of a bag."""
    times = [m.log_time_ns for m in read_bag(bag, [FRAME_TOPIC])]
    if len(times) < 2:
        return 1.0 / 15.0
    return float(np.median(np.diff(times))) / 1e9


def rss_trend_mb_per_min(samples: list[float]) -> float:
    """Least-squares slope of 1 Hz RSS samples, MiB per minute."""
    values = np.asarray([s for s in samples if np.isfinite(s)])
    if len(values) < 3:
        return float('nan')
    return float(np.polyfit(np.arange(len(values)) / 60.0, values, 1)[0])


def hop_latencies(result) -> list[tuple[str, str]]:
    """Where a posed frame's latency goes: source stamp -> localiser labels -> classifier
    classes -> first PoseStamped, each as arrival times at the monitor (p50 / p95 ms)."""
    first_pose: dict[int, int] = {}
    for pose in result.poses:
        first_pose[pose.stamp_ns] = min(pose.received_ns, first_pose.get(pose.stamp_ns,
                                                                         pose.received_ns))
    labels = result.stage_arrivals.get('localiser', {})
    classes = result.stage_arrivals.get('classifier', {})
    stamps = [s for s in first_pose if s in labels and s in classes]
    if not stamps:
        return []
    hops = {'stamp -> localiser labels': [labels[s] - s for s in stamps],
            'labels -> classifier classes': [classes[s] - labels[s] for s in stamps],
            'classes -> first pose': [first_pose[s] - classes[s] for s in stamps]}
    return [(name, f'{np.percentile(v, 50) / 1e6:.1f} / {np.percentile(v, 95) / 1e6:.1f} ms')
            for name, v in hops.items()]


def stages_alone(bag: str, classifier: str, templates: str, config: Path
                 ) -> dict[str, dict[str, float]]:
    """``tlessbot bench nodes`` on ``bag`` in a child process, with the node parameters of
    ``config`` (the graph's: views in parallel or not, pose workers): per stage, median / p90
    ms and CPU ms per frame."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / 'stages.json'
        subprocess.run([sys.executable, '-m', 'tlessbot_ros.tools.cli', 'bench', 'nodes',
                        '--bag', bag, '--repeats', '3', '--json', str(out),
                        '--classifier', classifier, '--templates', templates,
                        '--config', str(config)],
                       check=True, stdout=subprocess.DEVNULL)
        return json.loads(out.read_text())


def ratio_rows(alone: dict[str, dict[str, float]], p95_ms: float, duration_s: float,
               result, cores: int | None = None) -> list[tuple[str, str]]:
    """The host-independent figures: the graph against its stages alone, same run.

    The last row is the host's ceiling: the frames per second its ``cores`` (default: those
    this process may run on) could process at the stages' own CPU per frame, with no graph
    overhead at all, after the replay and monitor and whatever else took the host's cores
    meanwhile (a CPU hog, the hypervisor's steal: the host's time not idle beyond the graph's,
    from ``result.host_ticks``).
    Throughput against 1 / slowest stage alone cannot pass that ratio however the graph is
    scheduled.
    """
    medians = {name: figures['median_ms'] for name, figures in alone.items()}
    total, slowest = sum(medians.values()), max(medians.values())
    processed = float(result.diagnostics.get('pose_estimator', {}).get('frames', 'nan'))
    nodes = [label for label in result.cpu_s if label in alone]
    graph_cpu_s = sum(result.cpu_s[label] for label in nodes)
    graph_cpu_ms = 1e3 * graph_cpu_s / max(processed, 1.0)
    own_cpu_ms = sum(figures['cpu_ms_per_frame'] for figures in alone.values())
    fps = processed / max(duration_s, 1e-9)
    cores = len(os.sched_getaffinity(0)) if cores is None else cores
    monitor_cores = result.cpu_s.get(MONITOR, 0.0) / max(duration_s, 1e-9)
    graph_cores = graph_cpu_s / max(duration_s, 1e-9)
    shares = host_shares(result.host_ticks)
    # the host's time neither idle nor the graph's: other processes, and the hypervisor's steal
    other_cores = 0.0 if shares is None else \
        max(0.0, cores * (1.0 - shares[0]) - graph_cores - monitor_cores)
    ceiling_fps = (cores - monitor_cores - other_cores) * 1e3 / max(own_cpu_ms, 1e-9)
    return [
        ('stages alone, median ms/frame (bench nodes, same bag)',
         ', '.join(f'{name} {ms:.1f}' for name, ms in medians.items()) + f'; sum {total:.1f}'),
        ('p95 latency / sum of the stages alone', f'{p95_ms / total:.2f}'),
        ('frames processed per s / (1 / slowest stage alone)',
         f'{fps:.2f} / {1e3 / slowest:.2f} = {fps * slowest / 1e3:.2f}'),
        ("CPU of the three nodes per processed frame / the stages' own CPU per frame",
         f'{graph_cpu_ms:.1f} / {own_cpu_ms:.1f} ms = {graph_cpu_ms / max(own_cpu_ms, 1e-9):.2f}'),
        ("ceiling: frames/s the cores left by the replay and monitor (and others) "
         "give at the stages' own CPU per frame, / (1 / slowest stage alone)",
         f'({cores} - {monitor_cores:.2f} - {other_cores:.2f}) cores / {own_cpu_ms:.1f} ms = '
         f'{ceiling_fps:.2f} / {1e3 / slowest:.2f} = {ceiling_fps * slowest / 1e3:.2f}'),
    ]


def window_table(result, window_s: float) -> str:
    """A soak's figures per window of ``window_s`` seconds: frames answered, latency p50 / p95,
    and per node RSS, open file descriptors and threads at the window's end; then the trends
    (RSS slope over the last two thirds, the range of fds and threads after the first window)."""
    if not result.sample_times_s or window_s <= 0:
        return ''
    windows = int(result.sample_times_s[-1] // window_s) + 1
    nodes = sorted(result.rss_mb_samples)
    header = ['window (min)', 'frames answered', 'latency p50 / p95 (ms)'] + [
        f'{n}: RSS MiB / fds / threads' for n in nodes]
    lines = ['| ' + ' | '.join(header) + ' |', '|' + '---|' * len(header)]
    times = np.asarray(result.sample_times_s)
    for w in range(windows):
        start_ns = result.replay_start_ns + int(w * window_s * 1e9)
        end_ns = start_ns + int(window_s * 1e9)
        poses = [p for p in result.poses if start_ns <= p.received_ns < end_ns]
        latency = np.array([(p.received_ns - p.stamp_ns) / 1e6 for p in poses])
        last = int(np.searchsorted(times, (w + 1) * window_s) - 1)
        cells = [f'{w * window_s / 60:.0f}-{(w + 1) * window_s / 60:.0f}',
                 str(len({p.stamp_ns for p in poses})),
                 f'{np.percentile(latency, 50):.1f} / {np.percentile(latency, 95):.1f}'
                 if len(latency) else '-']
        cells += [f'{result.rss_mb_samples[n][last]:.0f} / {result.fd_samples[n][last]} / '
                  f'{result.thread_samples[n][last]}' for n in nodes]
        lines.append('| ' + ' | '.join(cells) + ' |')
    lines += ['', '| node | RSS trend, last two thirds (MiB/min) | fds after the first window '
              '(min-max) | threads after the first window (min-max) |', '|---|---|---|---|']
    settled = int(np.searchsorted(times, window_s))
    for n in nodes:
        rss = result.rss_mb_samples[n]
        fds, threads = result.fd_samples[n][settled:], result.thread_samples[n][settled:]
        lines.append(f'| {n} | {rss_trend_mb_per_min(rss[len(rss) // 3:]):+.2f} | '
                     + (f'{min(fds)}-{max(fds)} | {min(threads)}-{max(threads)} |'
                        if fds else '- | - |'))
    return '\n'.join(lines)


def host_shares(ticks: tuple[list[int] | None, list[int] | None]
                ) -> tuple[float, float] | None:
    """The shares of the host's CPU time that were idle and stolen by the hypervisor between
    two /proc/stat readings (``read_cpu_ticks``); None without both."""
    start, end = ticks
    if start is None or end is None or sum(end) <= sum(start):
        return None
    delta = [b - a for a, b in zip(start, end)]
    total = sum(delta)
    return (delta[3] + delta[4]) / total, delta[7] / total


def host_rows(ticks: tuple[list[int] | None, list[int] | None]) -> list[tuple[str, str]]:
    """The host's idle and stolen CPU while replaying (/proc/stat): a run on a virtual machine
    whose hypervisor gave cores to other machines is slower for it, whatever the code."""
    shares = host_shares(ticks)
    if shares is None:
        return []
    idle, steal = shares
    return [('host while replaying: idle / stolen by the hypervisor',
             f'{100 * idle:.1f} % / {100 * steal:.1f} % of its CPU time')]


def split_rows(diagnostics: dict[str, dict[str, str]]) -> list[tuple[str, str]]:
    """How often each stage split a frame's work over a second core (parallel.*), from its
    last /diagnostics."""
    rows = []
    for label in sorted(diagnostics):
        values = diagnostics[label]
        if 'frames_split' in values:
            split = int(values['frames_split'])
            whole = int(values.get('frames_kept_whole', 0))
            rows.append((f'{label}: frames split over a second core',
                         f"{split} of {split + whole}; cores free beside its work lately "
                         f"{values.get('cores_free_beside_work', '?')}"))
    return rows


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.tools.support.bag_scoring import Estimate, frame_duplicates
    from tlessbot_ros.tools.support.graph_run import run_graph_on_bag
    from tlessbot_ros.tools.support.rig import load_rig

    config = Path(args.config) if args.config else default_config_path()
    alone = stages_alone(args.bag, args.classifier, args.templates, config) \
        if args.stages_alone else None
    interval = bag_frame_interval_s(args.bag)
    rate = args.fps * interval
    result = run_graph_on_bag(
        args.bag, config=config,
        rate=rate, loop=True, duration_s=args.duration, restamp=True, settle_s=3.0,
        ros_args=['-p', f'model_path:={args.classifier}',
                  '-p', f'templates_path:={args.templates}'])
    latencies = np.array([(p.received_ns - p.stamp_ns) / 1e6 for p in result.poses])
    answered = {p.stamp_ns for p in result.poses}
    replayed = result.frames_replayed
    dropped = sum(1 for stamp in replayed if stamp not in answered)
    by_frame: dict[int, list[Estimate]] = {}
    for p in result.poses:
        by_frame.setdefault(p.stamp_ns, []).append(Estimate(p.stamp_ns, p.obj_id, p.T, p.frame_id))
    rig = load_rig(config)
    duplicates = sum(frame_duplicates(poses, rig) for poses in by_frame.values())
    rows = [
        ('frames replayed', f'{len(replayed)} in {args.duration:.0f} s at {args.fps:.0f} fps'),
        ('poses received', str(len(result.poses))),
        ('latency p50 (source stamp -> PoseStamped)',
         f'{np.percentile(latencies, 50):.1f} ms' if len(latencies) else 'n/a'),
        ('latency p95', f'{np.percentile(latencies, 95):.1f} ms' if len(latencies) else 'n/a'),
        ('frames dropped (no pose back)',
         f'{dropped} ({100 * dropped / max(1, len(replayed)):.1f} %)'),
        ('duplicates per answered frame (one part, several poses)',
         f'{duplicates / max(1, len(by_frame)):.3f} ({duplicates} in {len(by_frame)} frames)'),
    ]
    for label in sorted(result.rss_mb_start):
        samples = result.rss_mb_samples.get(label, [])
        trend = rss_trend_mb_per_min(samples)
        late_trend = rss_trend_mb_per_min(samples[len(samples) // 2:])
        rows.append((f'RSS {label} start -> end',
                     f'{result.rss_mb_start[label]:.0f} -> {result.rss_mb_end[label]:.0f} MiB '
                     f'(trend {trend:+.2f} MiB/min; second half {late_trend:+.2f} MiB/min)'))
    if alone is not None and len(latencies):
        rows += ratio_rows(alone, float(np.percentile(latencies, 95)), args.duration, result)
    rows += [(f'{name} (p50 / p95)', value) for name, value in hop_latencies(result)]
    for label in sorted(result.cpu_s):
        values = result.diagnostics.get(label, {})
        rows.append((f'{label}: CPU while replaying, frames processed / dropped',
                     f'{100 * result.cpu_s[label] / max(args.duration, 1e-9):.0f} % of one core; '
                     f"{values.get('frames', '?')} / {values.get('dropped', '?')}"
                     + (f" (and about {values['unread_frames_est']} left unread in DDS)"
                        if 'unread_frames_est' in values else '') + '; '
                     f"processing p50 {values.get('latency_ms_p50', '?')} ms, "
                     f"p95 {values.get('latency_ms_p95', '?')} ms; input age at its start "
                     f"p50 {values.get('input_age_ms_p50', '?')} ms, "
                     f"p95 {values.get('input_age_ms_p95', '?')} ms"))
    rows += split_rows(result.diagnostics) + host_rows(result.host_ticks)
    table = '| measure | value |\n|---|---|\n' + '\n'.join(f'| {k} | {v} |' for k, v in rows)
    if args.duration >= 2 * args.window:
        table += '\n\n' + window_table(result, args.window)
    print(table)
    if args.out:
        Path(args.out).write_text(table + '\n')
    return 0
