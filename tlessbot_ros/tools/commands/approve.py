"""Replay a bag through the graph and write its poses as the expected answer for tlessbot check.

    tlessbot approve BAG --out expected.yaml [--config my_cell.yaml] [-p NAME:=VALUE]

Writes, per frame (source stamp) and part, the part's name, pose (with its frame) and score,
and a page for a person to check before committing it: expected.md with the side view's
overlay of every frame in expected_overlays/. Lock-step by default: the same answer every run.
Exit 0; 2 when the set-up is broken (no such bag, topics missing, graph not ready).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.tools.support.approval_run import add_replay_arguments, replay_bag


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_replay_arguments(parser)
    parser.add_argument('--out', type=Path, required=True,
                        help='expected-poses YAML to write (the page goes beside it, .md)')


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.tools.support.expected_poses import (
        ApprovedRun,
        frames_from_parts,
        write_expected,
    )
    from tlessbot_ros.tools.support.review_page import write_review_page

    try:
        outcome = replay_bag(args, overlays=True)
    except TlessbotError as error:
        print(f'tlessbot approve: error: {error}', file=sys.stderr)
        return 2
    frames = frames_from_parts(outcome.frames, outcome.parts)
    info = {'bag': str(args.bag), 'replay': 'free-running' if args.free_running else 'lockstep',
            'cameras': outcome.staged.cameras, 'parameters': list(args.param)}
    if args.config:
        info['config'] = str(args.config)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_expected(args.out, ApprovedRun(frames, info))
    page = args.out.with_suffix('.md')
    skipped = (f'; {outcome.staged.skipped} incomplete frame(s) of the bag left out'
               if outcome.staged.skipped else '')
    notes = [f'Bag `{args.bag}`, replayed {info["replay"]} in {outcome.seconds:.0f} s: '
             f'{len(frames)} frames, {len(outcome.parts)} parts{skipped}. Expected poses: '
             f'`{args.out.name}`. Check every overlay before committing both.']
    pngs = write_review_page(page, frames, outcome.overlays,
                             title=f'Approved poses of {args.bag}', notes=notes)
    print(f'approved {len(outcome.parts)} parts in {len(frames)} frames -> {args.out}; review '
          f'{page} ({pngs} overlays){skipped}')
    return 0
