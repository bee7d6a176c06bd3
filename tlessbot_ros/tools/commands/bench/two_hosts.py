"""Two hosts: the graph split over two network namespaces (UDP) against one host (shared memory).

    tlessbot bench two-hosts [--fps 5] [--duration 30] [--no-latency]     # root, Linux

Two network namespaces joined by a veth pair (:mod:`~tlessbot_ros.tools.support.netns`) stand
for the camera PC (A: the replay, the localiser and this benchmark's monitor) and the
perception PC (B: classifier and pose estimator). Everything between them (the localiser's
relayed camera messages and labels, the pose estimator's frame outcomes that pace the
localiser, the poses, /diagnostics) crosses the link over UDP with config/fastdds_udp.xml.
The one-host runs start all three nodes in A with the package's shared-memory profile.

1. Lock-step replay of the bag (every frame handled, deterministic): each two-host pose
   against the one-host pose of the same frame and part (5 cm / 5°, symmetry-aware).
2. With ``--duration``: replay restamped in a loop at ``--fps``; latency from a frame's source
   stamp to its PoseStamped arriving in A (p50 / p95) and the frames answered.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_MODELS_INFO, DEFAULT_TEMPLATES
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.support.defaults import DEFAULT_BAG

if TYPE_CHECKING:   # bag_scoring imports the numba kernels: seconds, for every bench's --help
    from tlessbot_ros.tools.support.bag_scoring import Estimate

# The nodes on the second host; the localiser stays with the cameras (and the replay).
REMOTE_NODES = ('classifier', 'pose_estimator')
GRAPH_TIMEOUT_S = 900.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', default=str(DEFAULT_BAG))
    parser.add_argument('--fps', type=float, default=5.0, help='frame rate of the latency runs')
    parser.add_argument('--duration', type=float, default=30.0,
                        help='seconds of each latency run')
    parser.add_argument('--no-latency', dest='latency', action='store_false',
                        help='only the lock-step pose comparison')
    parser.add_argument('--classifier', default=str(DEFAULT_CLASSIFIER))
    parser.add_argument('--templates', default=str(DEFAULT_TEMPLATES))
    parser.add_argument('--config', default=None)
    # One graph run inside a namespace (started by this benchmark and by the two-host test):
    parser.add_argument('--role', choices=('graph',), help=argparse.SUPPRESS)
    parser.add_argument('--remote-netns', default=None, help=argparse.SUPPRESS)
    parser.add_argument('--lockstep', action='store_true', help=argparse.SUPPRESS)
    parser.add_argument('--json', default=None, help=argparse.SUPPRESS)


def graph_role_argv(out: Path, *, bag: str, remote_netns: str | None, lockstep: bool,
                    fps: float = 5.0, duration_s: float = 0.0) -> list[str]:
    """The argv (this Python) of one graph run writing its poses to ``out`` as JSON; with
    ``remote_netns`` the classifier and the pose estimator start in that namespace."""
    argv = [sys.executable, '-m', 'tlessbot_ros.tools.cli', 'bench', 'two-hosts',
            '--role', 'graph', '--json', str(out), '--bag', bag, '--fps', str(fps),
            '--duration', str(duration_s)]
    if remote_netns:
        argv += ['--remote-netns', remote_netns]
    return argv + (['--lockstep'] if lockstep else [])


def _graph_role(args: argparse.Namespace) -> int:
    from tlessbot_ros.tools.commands.bench.graph import bag_frame_interval_s
    from tlessbot_ros.tools.support.graph_run import run_graph_on_bag
    from tlessbot_ros.tools.support.netns import NetworkNamespace

    prefixes = {}
    if args.remote_netns:
        prefix = NetworkNamespace(args.remote_netns, '', '').exec_prefix()
        prefixes = dict.fromkeys(REMOTE_NODES, prefix)
    config = Path(args.config) if args.config else default_config_path()
    ros_args = ['-p', f'model_path:={args.classifier}', '-p', f'templates_path:={args.templates}']
    if args.lockstep:
        result = run_graph_on_bag(args.bag, config=config, lockstep=True, ros_args=ros_args,
                                  node_prefixes=prefixes)
    else:
        result = run_graph_on_bag(args.bag, config=config,
                                  rate=args.fps * bag_frame_interval_s(args.bag), loop=True,
                                  duration_s=args.duration, restamp=True, ros_args=ros_args,
                                  node_prefixes=prefixes)
    Path(args.json).write_text(json.dumps({
        'poses': [{'stamp_ns': p.stamp_ns, 'obj_id': p.obj_id, 'T': p.T.tolist(),
                   'frame_id': p.frame_id, 'received_ns': p.received_ns}
                  for p in result.poses],
        'frames_replayed': result.frames_replayed}))
    return 0


@dataclass
class GraphRunPoses:
    """What a graph run wrote: its poses, when each arrived (ns), the replayed frames' stamps."""

    poses: list[Estimate]
    received_ns: list[int]
    frames_replayed: list[int]


def load_graph_run(path: Path) -> GraphRunPoses:
    """A graph run's JSON (written with ``--role graph``)."""
    from tlessbot_ros.tools.support.bag_scoring import Estimate

    data = json.loads(path.read_text())
    return GraphRunPoses(
        [Estimate(p['stamp_ns'], p['obj_id'], np.asarray(p['T']), p['frame_id'])
         for p in data['poses']],
        [p['received_ns'] for p in data['poses']], data['frames_replayed'])


def _run_in(namespace, argv: list[str], env: dict[str, str]) -> None:
    try:
        completed = subprocess.run([*namespace.exec_prefix(), *argv], env=env,
                                   capture_output=True, text=True, timeout=GRAPH_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        sys.exit(f'bench two-hosts: a graph run took longer than {GRAPH_TIMEOUT_S:.0f} s')
    if completed.returncode != 0:
        sys.exit(f'bench two-hosts: a graph run failed:\n{completed.stderr[-3000:]}')


def _latency_row(name: str, run: GraphRunPoses) -> str:
    latencies = np.array([(received - pose.stamp_ns) / 1e6
                          for pose, received in zip(run.poses, run.received_ns)])
    answered = {pose.stamp_ns for pose in run.poses}
    replayed = run.frames_replayed
    share = 100.0 * sum(stamp in answered for stamp in replayed) / max(1, len(replayed))
    timing = (f'{np.percentile(latencies, 50):.0f} / {np.percentile(latencies, 95):.0f} ms'
              if len(latencies) else 'n/a')
    return f'| {name} | {len(replayed)} | {share:.0f} % | {timing} |'


def run(args: argparse.Namespace) -> int:
    if args.role == 'graph':
        return _graph_role(args)
    from tlessbot_ros.nodes.common import DDS_PROFILE_VARIABLES, use_package_dds_profile
    from tlessbot_ros.tools.support.bag_scoring import compare_pose_sets
    from tlessbot_ros.tools.support.models_info import load_symmetries
    from tlessbot_ros.tools.support.netns import two_namespaces, udp_environ

    base = {k: v for k, v in os.environ.items() if k not in DDS_PROFILE_VARIABLES}
    one_host = dict(base, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    use_package_dds_profile(one_host)
    runs = [('lockstep', True, 0.0)] + ([('latency', False, args.duration)]
                                        if args.latency else [])
    results = {}
    with tempfile.TemporaryDirectory() as scratch, \
            two_namespaces('tlessbot-two-hosts') as (host_a, host_b):
        two_hosts = udp_environ(base, [host_a.address, host_b.address])
        for kind, lockstep, duration_s in runs:
            for setting, env, remote in (('one host', one_host, None),
                                         ('two hosts', two_hosts, host_b.name)):
                out = Path(scratch) / f'{kind}-{setting.replace(" ", "-")}.json'
                print(f'bench two-hosts: {kind} run, {setting} ...', flush=True)
                _run_in(host_a, graph_role_argv(out, bag=args.bag, remote_netns=remote,
                                                lockstep=lockstep, fps=args.fps,
                                                duration_s=duration_s), env)
                results[kind, setting] = load_graph_run(out)
    reference = results['lockstep', 'one host'].poses
    other = results['lockstep', 'two hosts'].poses
    comparison = compare_pose_sets(reference, other, load_symmetries(DEFAULT_MODELS_INFO))
    errors = comparison.errors
    print(f'lock-step, {args.bag}: {len(reference)} poses on one host, {len(other)} on two '
          f'hosts; {comparison.within_5cm_5deg} of {len(errors)} pairs within 5 cm / 5 deg; '
          f'largest difference {1e3 * max((e.translation_m for e in errors), default=0):.2f} mm'
          f' / {max((e.rotation_deg for e in errors), default=0):.2f} deg; unpaired: '
          f'{comparison.unpaired_reference} one-host, {comparison.unpaired_other} two-host')
    if args.latency:
        print(f'\nrestamped replay at {args.fps:g} fps for {args.duration:g} s, latency from '
              'the source stamp to the PoseStamped:\n')
        print('| graph | frames replayed | frames answered | latency p50 / p95 |')
        print('|---|---|---|---|')
        for setting in ('one host', 'two hosts'):
            print(_latency_row(setting, results['latency', setting]))
    return 0
