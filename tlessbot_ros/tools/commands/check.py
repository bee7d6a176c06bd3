"""Replay a bag through the graph and compare its poses with the approved ones (for CI).

    tlessbot check BAG --expected expected.yaml [--junit report.xml]
                   [--position-tolerance-mm 5] [--angle-tolerance-deg 2]

Matches the parts frame by frame (same name, nearest pose, the models' symmetries respected)
and prints a table. Exit 0: every part matches; 1: a regression (a part missing, added,
moved beyond the tolerance, in another frame or under another name), each named with its
frame; 2: the set-up is broken (no such bag, topics missing, graph not ready), one line.
"""
from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from tlessbot_ros.core.regression import MATCH, PartCheck, Tolerance, check_frames
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.tools.support.approval_run import (
    add_replay_arguments,
    bag_cameras,
    replay_bag,
)
from tlessbot_ros.tools.support.bag_inputs import SetupError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tlessbot_ros.data import DEFAULT_MODELS_INFO

    add_replay_arguments(parser)
    parser.add_argument('--expected', type=Path, required=True,
                        help='expected-poses YAML from tlessbot approve')
    parser.add_argument('--position-tolerance-mm', type=float, default=5.0,
                        help='largest position change of a part, mm (default 5)')
    parser.add_argument('--angle-tolerance-deg', type=float, default=2.0,
                        help='largest rotation change of a part, symmetries respected, deg '
                             '(default 2)')
    parser.add_argument('--models-info', type=Path, default=DEFAULT_MODELS_INFO,
                        help="BOP models_info.json with the parts' symmetries "
                             '(default: the packaged T-LESS one)')
    parser.add_argument('--junit', type=Path, help='also write JUnit XML here')


def format_table(checks: Sequence[PartCheck], frame_index: dict[int, int]) -> str:
    """The check's table: one row per part of each frame."""
    rows = [('frame', 'stamp (s)', 'part', 'result', 'moved mm', 'moved deg', 'score')]
    for check in checks:
        error = check.error
        scores = [p.score for p in (check.expected, check.actual) if p is not None]
        rows.append((str(frame_index.get(check.stamp_ns, '-')), f'{check.stamp_ns / 1e9:.3f}',
                     check.name if check.status != 'renamed' else
                     f'{check.expected.name} -> {check.actual.name}',
                     'ok' if check.ok else check.status.upper(),
                     '' if error is None else f'{1e3 * error.translation_m:.2f}',
                     '' if error is None else f'{error.rotation_deg:.2f}',
                     ' -> '.join('?' if s is None else f'{s:.2f}' for s in scores)))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    return '\n'.join('  '.join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip()
                     for row in rows)


def _symmetries(path: Path) -> dict:
    from tlessbot_ros.tools.support.models_info import load_symmetries

    return {f'obj_{obj_id:02d}': s for obj_id, s in load_symmetries(path).items()}


def _same_cameras(approved: object, found: dict[str, str]) -> None:
    """The bag gives the graph the cameras the approved run had (the set-up is broken when a
    camera's topics went missing from a bag approved with two).

    Raises:
        SetupError: other cameras; one line.
    """
    if isinstance(approved, dict) and set(approved) != set(found):
        given = ', '.join(f'{camera} ({prefix})' for camera, prefix in found.items())
        raise SetupError(f'the poses were approved with the cameras {", ".join(approved)}, '
                         f'but the bag has {given}')


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.tools.support.expected_poses import frames_from_parts, read_expected
    from tlessbot_ros.tools.support.junit import write_junit

    try:
        tolerance = Tolerance(1e-3 * args.position_tolerance_mm, args.angle_tolerance_deg)
        expected = read_expected(args.expected)
        symmetries = _symmetries(args.models_info)
        _same_cameras(expected.info.get('cameras'), bag_cameras(args)[2])
        outcome = replay_bag(args)
    except (TlessbotError, ValueError) as error:
        print(f'tlessbot check: error: {error}', file=sys.stderr)
        return 2
    actual = frames_from_parts(outcome.frames, outcome.parts)
    checks = check_frames(expected.frames, actual, symmetries, tolerance)
    frame_index = {s: i for i, s in enumerate(sorted(set(expected.frames) | set(actual)))}
    print(format_table(checks, frame_index))
    if args.junit:
        write_junit(args.junit, checks, suite=f'tlessbot check {args.bag}',
                    frame_index=frame_index, seconds=outcome.seconds)
    failed = [c for c in checks if c.status != MATCH]
    mode = 'free-running' if args.free_running else 'lock-step'
    if not failed:
        errors = [c.error for c in checks if c.error is not None]
        largest = (f'largest change {1e3 * max(e.translation_m for e in errors):.2f} mm, '
                   f'{max(e.rotation_deg for e in errors):.2f} deg; ' if errors else '')
        print(f'check: all {len(checks)} parts match in {len(actual)} frames ({mode}, '
              f'{outcome.seconds:.0f} s; {largest}tolerance {1e3 * tolerance.position_m:g} mm, '
              f'{tolerance.angle_deg:g} deg)')
        return 0
    print(f'check: REGRESSION: {len(failed)} of {len(checks)} parts in '
          f'{len({c.stamp_ns for c in failed})} of {len(actual)} frames ({mode}):')
    for check in failed:
        print(f'  frame {frame_index[check.stamp_ns]} (stamp {check.stamp_ns / 1e9:.3f} s) '
              f'{check.name}: {check.describe()}')
    return 1
