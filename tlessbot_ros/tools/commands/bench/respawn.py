"""Kill each stage node in turn under tlessbot launch: time to the next correct pose, wrong poses.

    tlessbot bench respawn --bag BAG --config RIG.yaml [--nodes localiser classifier ...]

Runs the graph once in lock-step (the reference: which poses it gets wrong without any kill),
then starts ``tlessbot launch`` with the stage nodes, replays the bag free-running in a loop
(restamped: each frame sent has its own stamp) and, once correct poses come, kills each node
of ``--nodes`` with SIGKILL, one after the other, waiting each time until the node is ready
again and a correct pose of a frame sent after the kill has come. Prints per node: seconds
from the kill until its new process was ready and until the next correct pose, that time in
units of the graph's start-up (launch's "graph ready in", same run), poses wrong beyond
lock-step's, results of frames from before the kill published after the restart, and the
node's child processes (pose workers) still alive after it. The bag needs /ground_truth topics
(``tlessbot simulate --bag``).
"""
from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path

from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_MODELS_INFO, DEFAULT_TEMPLATES
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.support.processes import PERCEPTION_NODES


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', required=True, help='bag with ground truth')
    parser.add_argument('--config', default=None, help="parameter YAML with the bag's rig")
    parser.add_argument('--nodes', nargs='+', default=list(PERCEPTION_NODES),
                        choices=PERCEPTION_NODES, help='nodes to kill, in this order')
    parser.add_argument('--pose-workers', type=int, default=1,
                        help="the pose estimator's worker processes (workers.count)")
    parser.add_argument('--classifier', default=str(DEFAULT_CLASSIFIER))
    parser.add_argument('--templates', default=str(DEFAULT_TEMPLATES))
    parser.add_argument('--json', default=None, help='write the figures here')
    parser.add_argument('--echo', action='store_true', help="print launch's output as it comes")


def _row(kill, graph_ready_s: float) -> str:
    def seconds(value: float | None) -> str:
        return '-' if value is None else f'{value:.1f}'
    ratio = '-' if kill.next_correct_s is None else f'{kill.next_correct_s / graph_ready_s:.2f}'
    return (f'| {kill.node} | {seconds(kill.ready_again_s)} | {seconds(kill.next_correct_s)} | '
            f'{ratio} | {kill.wrong_poses} | {kill.late_outputs} | {len(kill.orphans)} |')


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.errors import TlessbotError
    from tlessbot_ros.tools.support.models_info import load_symmetries
    from tlessbot_ros.tools.support.respawn_trial import lockstep_reference, run_respawn_trial

    if not Path(args.bag).exists():
        raise TlessbotError(f'bag not found: {args.bag}')
    config = Path(args.config) if args.config else default_config_path()
    params = [f'model_path:={args.classifier}', f'templates_path:={args.templates}',
              f'workers.count:={args.pose_workers}']
    symmetries = load_symmetries(DEFAULT_MODELS_INFO)
    reference = lockstep_reference(args.bag, config=config, symmetries=symmetries,
                                   params=params)
    trial = run_respawn_trial(args.bag, config=config, symmetries=symmetries,
                              reference_wrong=reference, nodes=args.nodes, params=params,
                              echo=print if args.echo else None)
    lines = [f'graph ready in {trial.graph_ready_s:.1f} s (launch, this run); '
             f'{trial.frames_sent} frames sent, {trial.poses} poses; wrong poses before the '
             f'first kill: {trial.baseline_wrong}', '',
             '| killed (SIGKILL) | ready again (s) | next correct pose (s) | / graph ready | '
             'wrong poses | late results | orphans |', '|---|---|---|---|---|---|---|']
    lines += [_row(kill, trial.graph_ready_s) for kill in trial.kills]
    if trial.foreign_poses:
        lines += ['', f'WARNING: {trial.foreign_poses} poses of frames this replay never sent '
                  '(another graph on this ROS_DOMAIN_ID?); not counted above']
    print('\n'.join(lines))
    if args.json:
        Path(args.json).write_text(json.dumps({
            'graph_ready_s': trial.graph_ready_s, 'baseline_wrong': trial.baseline_wrong,
            'frames_sent': trial.frames_sent, 'poses': trial.poses,
            'foreign_poses': trial.foreign_poses,
            'kills': [asdict(kill) for kill in trial.kills]}, indent=1))
    return 0
