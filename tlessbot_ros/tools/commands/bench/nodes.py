"""Node callbacks in-process: ms per frame of each stage node's process() on a bag's frames.

    tlessbot bench nodes [--bag bags/demo] [--repeats 3] [--config config/cell.yaml] [--json FILE]
                         [--idle-before-ms MS [--idle-busy]]

The bag's camera messages are read as a node's subscription delivers them (images in place,
the rest through rclpy) and fed straight to LocaliserNode, ClassifierNode and PoseEstimatorNode,
each frame on the node's own frame thread as in the graph (no DDS; the pose estimator's worker
processes are the only other ones), with the node
parameters of ``--config`` as the graph runs them: each stage's labels or
classes are the next one's input. The figure is the node's own cost per frame (conversions,
core, building the outgoing messages); what the graph adds on top of it is transport, waiting
and the other nodes' share of the CPU (``tlessbot bench graph``, which runs this first and
compares). ``--json`` also writes, per stage, the median and p90 ms per frame and the CPU ms
per frame (this process and its children: the pose estimator's worker counts).

``--idle-before-ms`` waits that long before each stage's frame, as a stage in the graph waits
for its input between frames, and ``--idle-busy`` spins through the wait instead of sleeping.
Against the back-to-back default, the first shows what a frame costs after the host's cores
went idle; the second, whether the wait itself (not the pause in the work) is what costs
(docs/bench/backpressure.md).
"""
from __future__ import annotations

import argparse
import json
import os
import time
from functools import partial
from pathlib import Path

import numpy as np

from tlessbot_ros.conversions.image_cdr import image_from_cdr
from tlessbot_ros.conversions.topics import COLOR, DEPTH, DEPTH_INFO, camera_topic
from tlessbot_ros.core.common import CAMERA_NAMES
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.support.defaults import DEFAULT_BAG

INPUTS = {'color': COLOR, 'depth': DEPTH, 'info': DEPTH_INFO}   # input name: camera-relative topic


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', default=str(DEFAULT_BAG), help='bag with camera topics')
    parser.add_argument('--repeats', type=int, default=3, help='passes over the frames')
    parser.add_argument('--config', default=None,
                        help='cell YAML whose node parameters the stages run with, as in the '
                             'graph (default: config/cell.yaml)')
    parser.add_argument('--pose-workers', type=int, default=None,
                        help="the pose estimator's worker processes (default: the config's "
                             'workers.count)')
    parser.add_argument('--classifier', default=None, help='model file (default: packaged)')
    parser.add_argument('--templates', default=None, help='templates file (default: packaged)')
    parser.add_argument('--json', default=None, metavar='FILE',
                        help='also write the per-stage figures as JSON here')
    parser.add_argument('--idle-before-ms', type=float, default=0.0, metavar='MS',
                        help="wait this long before each stage's frame (as a stage in the graph "
                             'waits for its input); default 0: back to back')
    parser.add_argument('--idle-busy', action='store_true',
                        help='spin through --idle-before-ms instead of sleeping (the cores '
                             'never go idle)')


class _Captured:
    """Stands in for a publisher: keeps the last message."""

    def __init__(self) -> None:
        self.last = None

    def publish(self, msg) -> None:
        self.last = msg

    def get_subscription_count(self) -> int:
        return 0


def bag_frames(bag: str) -> list[dict[str, dict]]:
    """The two-view frames of ``bag`` as a stage's ``process`` takes them: per frame,
    {camera: {'color', 'depth', 'info': deserialised message}}."""
    from tlessbot_ros.io.bags import read_bag
    from tlessbot_ros.nodes.common import message_class
    from tlessbot_ros.nodes.inputs import RawMessage

    topics = [camera_topic(c, t) for t in INPUTS.values() for c in CAMERA_NAMES]
    by_topic: dict[str, list] = {}
    for m in read_bag(bag, topics):
        by_topic.setdefault(m.topic, []).append(
            RawMessage(message_class(m.msgtype), m.raw).deserialise())
    count = min((len(v) for v in by_topic.values()), default=0)
    return [{c: {k: by_topic[camera_topic(c, t)][i] for k, t in INPUTS.items()}
             for c in CAMERA_NAMES} for i in range(count)]


def _timed_ms(call, *args) -> float:
    """Wall time of ``call(*args)`` in ms."""
    start = time.perf_counter()
    call(*args)
    return 1e3 * (time.perf_counter() - start)


def _first_pass_over_later(times_ms: list[float], frames: int) -> float | None:
    """Median ms of the first pass over ``frames`` frames / median of the later passes
    (None with a single pass)."""
    if len(times_ms) <= frames:
        return None
    return float(np.median(times_ms[:frames]) / np.median(times_ms[frames:]))


def _idle(seconds: float, *, busy: bool) -> None:
    """Wait ``seconds``: asleep, or spinning on the clock (``busy``)."""
    if seconds <= 0:
        return
    if not busy:
        time.sleep(seconds)
        return
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def start_stage_nodes(args: argparse.Namespace, config: str) -> tuple[list, str]:
    """The localiser, classifier and pose estimator nodes with the graph's parameters of
    ``config`` (and the options' model files and pose workers), and a line on what the figures
    depend on. Needs rclpy initialised."""
    from rclpy.parameter import Parameter

    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode

    localiser = LocaliserNode()
    classifier = ClassifierNode(parameter_overrides=[
        Parameter('model_path', value=args.classifier)] if args.classifier else [])
    pose = PoseEstimatorNode(parameter_overrides=[
        *([Parameter('workers.count', value=args.pose_workers)]
          if args.pose_workers is not None else []),
        *([Parameter('templates_path', value=args.templates)] if args.templates else [])])
    ran_with = (f'parameters of {config}: localiser parallel_views '
                f'{localiser.localise_params.parallel_views}, pose_estimator workers.count '
                f"{pose.get_parameter('workers.count').value}")
    return [localiser, classifier, pose], ran_with


def timed_passes(nodes: list, frames: list[dict[str, dict]], args: argparse.Namespace
                 ) -> tuple[dict[str, list[float]], dict[str, float]]:
    """Feed ``frames`` through the three stage nodes ``args.repeats`` times, each stage's
    labels or classes the next one's input: ms per frame of each stage's ``process`` on its
    frame thread, and each stage's CPU seconds (this process and the pose workers)."""
    from tlessbot_ros.tools.support.proc_stats import cpu_seconds, process_tree

    localiser, classifier, pose = nodes
    labels = {c: _Captured() for c in CAMERA_NAMES}
    classes = {c: _Captured() for c in CAMERA_NAMES}
    localiser._label_publishers, classifier._class_publishers = labels, classes
    pose._pose_publishers = {k: _Captured() for k in pose._pose_publishers}
    pose._markers, pose._overlay = _Captured(), _Captured()
    times: dict[str, list[float]] = {'localiser': [], 'classifier': [], 'pose_estimator': []}
    cpu_s = dict.fromkeys(times, 0.0)
    # This process and the pose workers, found once: a scan of all of /proc per reading
    # would be counted as the stages' CPU.
    tree = process_tree(os.getpid())

    def cpu_now() -> float:
        return sum(cpu_seconds(pid, descendants=False) for pid in tree)
    for _ in range(max(1, args.repeats)):
        for frame in frames:
            views = {c: dict(msgs) for c, msgs in frame.items()}
            for name, node, outputs, key in (('localiser', localiser, labels, 'labels'),
                                             ('classifier', classifier, classes, 'classes'),
                                             ('pose_estimator', pose, None, None)):
                _idle(args.idle_before_ms / 1e3, busy=args.idle_busy)
                cpu0 = cpu_now()
                # on the node's frame thread, where the graph runs it (and warmed it up)
                times[name].append(node.on_frame_thread(
                    partial(_timed_ms, node.process, views)).result())
                cpu_s[name] += cpu_now() - cpu0
                if outputs is not None:
                    for c in views:   # the nodes publish images as CDR bytes
                        views[c][key] = image_from_cdr(outputs[c].last)
    return times, cpu_s


def timing_table(times: dict[str, list[float]], ready_s: dict[str, float], frames: int
                 ) -> list[str]:
    """Markdown rows per stage: ready time, median / p90 / first-frame ms and the first pass
    over ``frames`` frames against the later passes."""
    # The first frame after "ready" against the rest: a warm-up that covers every path the
    # first frame takes makes the ratio about 1 (the frame itself may be a busy one: compare
    # with the same frame's later passes, the last column).
    # The first pass over the frames against the later passes over the same frames shows
    # a cold start that lasts several frames (a thread warmed up elsewhere took 4-6).
    lines = ['| node | ready after (s) | median ms/frame | p90 ms | first frame ms | '
             'first / median | same frame, later passes (median ms) | '
             'first pass / later passes (medians) |',
             '|---|---|---|---|---|---|---|---|']
    for name, v in times.items():
        later = v[frames::frames]
        ratio = _first_pass_over_later(v, frames)
        lines.append(f'| {name} | {ready_s[name]:.1f} | {np.median(v):.1f} | '
                     f'{np.percentile(v, 90):.1f} | {v[0]:.1f} | {v[0] / np.median(v):.2f} | '
                     + (f'{np.median(later):.1f} | {ratio:.2f} |' if later else '- | - |'))
    return lines


def run(args: argparse.Namespace) -> int:
    import rclpy

    from tlessbot_ros.nodes.common import init_ros, limit_blas_threads

    frames = bag_frames(args.bag)
    if not frames:
        print(f'no two-view camera frames in {args.bag}')
        return 1
    limit_blas_threads()   # as every node process does (run_node): the same work, the same CPU
    config = args.config or str(default_config_path())
    init_ros(['--ros-args', '--params-file', config])   # the graph's parameters, per node name
    try:
        nodes, ran_with = start_stage_nodes(args, config)
        ready_s = {}
        for name, node in zip(('localiser', 'classifier', 'pose_estimator'), nodes):
            if not node.wait_ready():
                print(f'{name} did not get ready: {node.last_error}')
                return 1
            ready_s[name] = node.ready_after_s
        times, cpu_s = timed_passes(nodes, frames, args)
        for node in nodes:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    lines = timing_table(times, ready_s, len(frames))
    load = ', '.join(f'{v:.2f}' for v in os.getloadavg())
    lines += ['', f'{len(frames)} frames x {max(1, args.repeats)} passes from {args.bag}; '
              f'load average {load} on {os.cpu_count()} cores.', ran_with + '.']
    if args.idle_before_ms > 0:
        lines.append(f"{args.idle_before_ms:g} ms {'spent spinning' if args.idle_busy else 'idle'}"
                     " before each stage's frame.")
    print('\n'.join(lines))
    if args.json:
        Path(args.json).write_text(json.dumps({name: {
            'median_ms': float(np.median(v)), 'p90_ms': float(np.percentile(v, 90)),
            'first_frame_ms': v[0],
            'first_pass_over_later': _first_pass_over_later(v, len(frames)),
            'cpu_ms_per_frame': 1e3 * cpu_s[name] / len(v)} for name, v in times.items()},
            indent=1))
    return 0
