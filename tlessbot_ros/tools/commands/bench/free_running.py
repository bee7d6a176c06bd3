"""Free-running replays against lock-step: is the answer the same whatever the timing?

    tlessbot bench free-running --bag BAG --config RIG.yaml --runs 10 [--rate 1]

Runs the graph once in lock-step (each frame sent once the previous one is answered: the
reference) and ``--runs`` times free-running at the bag's own rate (x ``--rate``), each run in
a fresh graph started and replayed only once every stage reports ready. Prints, per run and
over the runs: the share of parts within 5 cm / 5 deg, frames answered, false positives and
duplicates (one part published more than once) per frame, and the ratio of the worst run to
lock-step. The bag needs /ground_truth topics (``tlessbot simulate --bag``).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_MODELS_INFO, DEFAULT_TEMPLATES
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', required=True, help='bag with ground truth')
    parser.add_argument('--config', default=None, help="parameter YAML with the bag's rig")
    parser.add_argument('--runs', type=int, default=10, help='free-running runs')
    parser.add_argument('--rate', type=float, default=1.0, help='replay rate factor')
    parser.add_argument('--classifier', default=str(DEFAULT_CLASSIFIER))
    parser.add_argument('--templates', default=str(DEFAULT_TEMPLATES))
    parser.add_argument('--json', default=None, help="write every run's summary here")
    parser.add_argument('--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='a parameter for every node after the config, e.g. '
                             'rig_refinement.mode:=none (repeatable)')


def _row(name: str, summary: dict) -> str:
    frames = max(1, summary['frames'])
    return (f'| {name} | {100 * summary["recall_5cm5deg"]:.1f} % '
            f'({summary["correct_5cm5deg"]}/{summary["parts_scored"]}) | '
            f'{summary["frames_answered"]}/{summary["frames"]} | '
            f'{summary["false_positives"] / frames:.2f} | {summary["duplicates"] / frames:.2f} |')


def _rig_line(name: str, summary: dict) -> str:
    """The localiser's rig refinement at the end of a run ('' without it): which rig it
    fused with, and its cost per frame against the localiser's median frame time."""
    values = summary.get('node_diagnostics', {}).get('localiser', {})
    if 'rig_in_use' not in values:
        return ''
    cost = float(values.get('rig_ms_per_frame', 'nan'))
    frame = float(values.get('latency_ms_p50', 'nan'))
    return (f'{name}: localiser rig {values["rig_in_use"]} ({values.get("rig_state")}, '
            f'{values.get("rig_frames_matched", 0)} frames matched), top->side '
            f'{values.get("rig_config_top_side_deg", "?")} deg / '
            f'{values.get("rig_config_top_side_mm", "?")} mm from the config; refinement '
            f'{cost:.1f} ms per frame of a {frame:.1f} ms median localiser frame '
            f'({cost / (frame - cost):.2f} x the rest)')


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from tlessbot_ros.tools.commands.demo import run_demo
    from tlessbot_ros.tools.support.models_info import load_symmetries

    config = Path(args.config) if args.config else default_config_path()
    bad = [value for value in args.param if ':=' not in value]
    if bad:
        raise TlessbotError(f'--param takes NAME:=VALUE, got {bad}')
    common = dict(config=config, classifier=args.classifier, templates=args.templates,
                  symmetries=load_symmetries(DEFAULT_MODELS_INFO), echo=False,
                  parameters=args.param)
    reference = run_demo(args.bag, lockstep=True, **common)
    runs = [run_demo(args.bag, lockstep=False, rate=args.rate, **common)
            for _ in tqdm(range(args.runs), desc='free-running runs', unit='run')]
    shares = [r['recall_5cm5deg'] for r in runs]
    lines = ['| run | within 5 cm / 5 deg | frames answered | false positives / frame | '
             'duplicates / frame |', '|---|---|---|---|---|', _row('lock-step', reference)]
    lines += [_row(f'free {k + 1}', r) for k, r in enumerate(runs)]
    worst = min(shares) if shares else float('nan')
    base = reference['recall_5cm5deg']
    ratio = worst / base if base else float('nan')
    lines += ['', f'free-running over {len(runs)} runs at {args.rate:g} x the recorded rate: '
              f'min {100 * worst:.1f} %, max {100 * max(shares):.1f} %; lock-step '
              f'{100 * base:.1f} %; min / lock-step = {ratio:.3f}; '
              f'duplicates {sum(r["duplicates"] for r in runs)} in all runs.']
    named = [('lock-step', reference), *((f'free {k + 1}', r) for k, r in enumerate(runs))]
    lines += [''] + [line for line in (_rig_line(name, r) for name, r in named) if line]
    print('\n'.join(lines))
    if args.json:
        Path(args.json).write_text(json.dumps({'lockstep': reference, 'runs': runs}, indent=1))
    return 0
