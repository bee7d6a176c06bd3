"""Replay the demo bag through the whole graph and check every pose against ground truth.

    tlessbot demo                     # bags/demo, packaged classifier and templates
    tlessbot demo --bag run.mcap --rate 0.5

The three perception nodes run as separate processes talking over DDS; this process replays
the bag and listens to /objects/obj_NN/pose. For every frame it prints the parts found, their
poses and their errors against the bag's /ground_truth topics, then a summary.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import Symmetries, rpy_from_matrix
from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_MODELS_INFO, DEFAULT_TEMPLATES
from tlessbot_ros.errors import ModelFileError, TlessbotError
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.io.ground_truth import read_ground_truth
from tlessbot_ros.tools.support.defaults import DEFAULT_BAG
from tlessbot_ros.tools.support.models_info import load_symmetries


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', default=str(DEFAULT_BAG), help='bag with ground truth')
    parser.add_argument('--config', default=None, help='parameter YAML (config/cell.yaml)')
    parser.add_argument('--classifier', default=str(DEFAULT_CLASSIFIER), help='model .npz')
    parser.add_argument('--templates', default=str(DEFAULT_TEMPLATES), help='templates .npz')
    parser.add_argument('--models-info', default=str(DEFAULT_MODELS_INFO),
                        help='BOP models_info.json with the symmetries used for scoring')
    parser.add_argument('--rate', type=float, default=1.0,
                        help='replay rate with --realtime (default 1)')
    parser.add_argument('--realtime', action='store_true',
                        help='replay at the recorded rate (frames the graph cannot keep up '
                             'with are dropped); default: frame by frame, each once the pose '
                             'estimator has handled the previous one')
    parser.add_argument('--json', default=None, help='also write the summary here')


def run_demo(bag: str, *, config: Path, classifier: str, templates: str,
             symmetries: dict[int, Symmetries], rate: float = 1.0, lockstep: bool = True,
             echo: bool = True, parameters: list[str] | None = None) -> dict:
    """Replay, collect, score; returns the summary (also printed when ``echo``).
    ``parameters``: ``NAME:=VALUE`` overrides for every node (after the config file)."""
    from tlessbot_ros.tools.support.bag_scoring import Estimate, frame_duplicates, score_frame
    from tlessbot_ros.tools.support.graph_run import run_graph_on_bag
    from tlessbot_ros.tools.support.rig import load_rig

    for path in (classifier, templates):
        if not Path(path).is_file():
            raise ModelFileError(f'model file not found: {path}')
    truth = read_ground_truth(bag)
    run = run_graph_on_bag(bag, config=config, rate=rate, lockstep=lockstep, ros_args=[
        '-p', f'model_path:={classifier}', '-p', f'templates_path:={templates}',
        *(arg for value in parameters or () for arg in ('-p', value))])
    estimates: dict[int, list[Estimate]] = {}
    for pose in run.poses:
        estimates.setdefault(pose.stamp_ns, []).append(
            Estimate(pose.stamp_ns, pose.obj_id, pose.T, pose.frame_id))
    rig = load_rig(config)
    scored = correct = false_pos = duplicates = 0
    per_frame = []
    t_err, r_err = [], []
    for index, stamp in enumerate(sorted(truth)):
        matches, extra = score_frame(truth[stamp], estimates.get(stamp, []), symmetries)
        false_pos += len(extra)
        repeated = frame_duplicates(estimates.get(stamp, []), rig)
        duplicates += repeated
        per_frame.append({'stamp_ns': stamp, 'parts': len(matches),
                          'correct': sum(m.correct for m in matches),
                          'poses': len(estimates.get(stamp, [])),
                          'false_positives': len(extra), 'duplicates': repeated})
        if echo:
            print(f'frame {index} (stamp {stamp / 1e9:.3f}): {len(matches)} parts >= 30 % '
                  f'visible, {len(estimates.get(stamp, []))} poses published'
                  + (f', {repeated} of them repeat a part' if repeated else ''))
        for match in matches:
            scored += 1
            part = match.truth
            if match.estimate is None:
                line = 'MISSED'
            else:
                correct += match.correct
                t_err.append(match.error.translation_m)
                r_err.append(match.error.rotation_deg)
                x, y, z = match.estimate.T[:3, 3]
                yaw = np.degrees(rpy_from_matrix(match.estimate.T[:3, :3]))[2]
                line = (f'({x:+.3f}, {y:+.3f}, {z:+.3f}) m yaw {yaw:+6.1f} deg in '
                        f'{match.estimate.frame_id}: error {1e3 * match.error.translation_m:.1f}'
                        f' mm / {match.error.rotation_deg:.1f} deg '
                        f'{"OK" if match.correct else "WRONG"}')
            if echo:
                print(f'  obj_{part.obj_id:02d} (visible {part.max_visib_fract:.0%}): {line}')
        for estimate in extra:
            if echo:
                print(f'  obj_{estimate.obj_id:02d}: published but matches no part '
                      '(false positive)')
    summary = {
        'frames': len(truth), 'parts_scored': scored, 'correct_5cm5deg': correct,
        'recall_5cm5deg': correct / scored if scored else 0.0,
        'false_positives': false_pos, 'poses_published': len(run.poses),
        'frames_answered': sum(1 for stamp in truth if estimates.get(stamp)),
        'duplicates': duplicates,
        'duplicates_per_frame': duplicates / len(truth) if truth else 0.0,
        'per_frame': per_frame,
        # seconds between frame publications; in lock-step each is one frame's trip through
        # the graph on this host (what it takes per frame now)
        'frame_intervals_s': [float(v) / 1e9 for v in np.diff(run.frames_replayed_at_ns)],
        'node_diagnostics': run.diagnostics,   # each stage node's last /diagnostics values
        'median_translation_error_mm': float(1e3 * np.median(t_err)) if t_err else None,
        'median_rotation_error_deg': float(np.median(r_err)) if r_err else None,
    }
    if echo:
        print(f'summary: {correct}/{scored} parts within 5 cm / 5 deg '
              f'({100 * summary["recall_5cm5deg"]:.1f} %), {false_pos} false positives, '
              f'{duplicates} duplicates, {summary["frames_answered"]}/{len(truth)} frames '
              'answered')
    return summary


def run(args: argparse.Namespace) -> int:
    config = Path(args.config) if args.config else default_config_path()
    if not Path(args.bag).exists():
        raise TlessbotError(f'bag not found: {args.bag}')
    summary = run_demo(args.bag, config=config, classifier=args.classifier,
                       templates=args.templates, symmetries=load_symmetries(args.models_info),
                       rate=args.rate, lockstep=not args.realtime)
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2))
    return 0
