"""Calibrate the rig from what the cameras see (a bag, or live) and write it into a cell YAML.

    tlessbot calibrate --bag BAG [--config config/cell.yaml] --out NEW.yaml
    tlessbot calibrate --live [--frames 60] [--timeout 120] --out NEW.yaml

Reads the aligned depth of both cameras (/top/..., /side/...) from a bag or, with --live,
from the running cameras (until --frames two-view frames or --timeout), finds the table in each
view (each camera's tilt and height) and the parts both views see (where the cameras stand
relative to each other on the table), and writes NEW.yaml: the --config file with only
``rig.<camera>.position_m / look_at_m / up`` changed. A bag of a minute of the cell at work
(1-6 parts on the table, moved between frames) is plenty; frames without parts cost nothing.

The scene cannot tell where the world origin lies on the table nor which way its x axis
points: those are kept from the --config file's top camera. The difference from --config is
printed per camera and for the top -> side transform, with the estimate's confidence; an
estimate that is not confident is not written unless --force.

    tlessbot calibrate --board --bag BAG --out NEW.yaml

measures the rig from a ChArUco board lying on the table instead (``tlessbot board`` prints
one; docs/calibrating.md).
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from itertools import islice
from pathlib import Path

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.tools.support.board_calibration import add_board_arguments


def add_arguments(parser: argparse.ArgumentParser) -> None:
    source = parser.add_mutually_exclusive_group()
    source.add_argument('--bag', help='bag with /top and /side aligned depth + camera_info')
    source.add_argument('--live', action='store_true',
                        help='read the running cameras (/top, /side aligned depth + '
                             'camera_info) instead of a bag')
    parser.add_argument('--config', type=Path, default=None,
                        help='cell YAML with the rig to start from (default config/cell.yaml)')
    parser.add_argument('--out', type=Path, required=True, help='cell YAML to write')
    parser.add_argument('--every', type=int, default=1, metavar='N',
                        help='use every N-th frame (default every frame)')
    parser.add_argument('--max-frames', type=int, default=60, metavar='N',
                        help='fit the latest N frames with parts in both views (default 60)')
    parser.add_argument('--frames', type=int, default=60, metavar='N',
                        help='--live: stop after N two-view frames (default 60)')
    parser.add_argument('--timeout', type=float, default=120.0, metavar='S',
                        help='--live: stop after S seconds (default 120)')
    parser.add_argument('--truth', type=Path, default=None,
                        help="a cell YAML with the bag's true rig (a simulated bag's): print the "
                             "estimate's errors against it (gauge-free)")
    parser.add_argument('--force', action='store_true',
                        help='write the rig even if the estimate is not confident')
    parser.add_argument('--board', action='store_true',
                        help='measure the rig from a ChArUco board lying on the table, seen in '
                             "the bag's colour images (tlessbot board prints one; --board-* "
                             'describe it and where it lies)')
    add_board_arguments(parser)


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.core.calibrate import SceneCalibrationParams
    from tlessbot_ros.io.config import default_config_path
    from tlessbot_ros.tools.support.calibration import (
        bag_frames,
        calibrate_from_frames,
        format_errors,
        format_report,
        live_frames,
    )
    from tlessbot_ros.tools.support.rig import load_rig, write_rig

    config = args.config or default_config_path()
    if args.every < 1 or args.max_frames < 1:
        raise TlessbotError('--every and --max-frames must be at least 1')
    if args.board:
        return _board(args, config)
    if not args.bag and not args.live:
        raise TlessbotError('give --bag BAG (a recording of both cameras) or --live')
    prior = load_rig(config)
    params = dataclasses.replace(SceneCalibrationParams(), max_frames=args.max_frames)
    t0 = time.perf_counter()
    if args.live:
        if args.frames < 1 or not args.timeout > 0:
            raise TlessbotError('--frames must be at least 1 and --timeout positive')
        frames = islice(live_frames(timeout_s=args.timeout), args.frames)
        source = 'the cameras'
    else:
        frames, source = bag_frames(args.bag), args.bag
    estimate, read = calibrate_from_frames(frames, prior, params=params, every=args.every)
    if estimate is None:
        raise TlessbotError(f'{source}: the table was not found in both views of any of '
                            f'{read} frames')
    print(format_report(estimate, frames_read=read, config=str(config)))
    print(f'time: {time.perf_counter() - t0:.1f} s ({estimate.solve_ms:.0f} ms to solve)')
    if args.truth:
        print(format_errors(load_rig(args.truth), estimate.rig, prior,
                            truth_name=str(args.truth)))
    if not estimate.confident and not args.force:
        raise TlessbotError('the estimate is not confident (see above): record more frames '
                            'with parts both cameras see, or write it anyway with --force')
    write_rig(config, estimate.rig, args.out, note='tlessbot calibrate from ' +
              ('the cameras' if args.live else Path(args.bag).name))
    print(f'wrote {args.out}')
    return 0


def _board(args: argparse.Namespace, config: Path) -> int:
    """The ChArUco board path (``core/calibrate/board.py``): the rig from the board in the
    bag's colour images, written as the scene path writes it."""
    from tlessbot_ros.tools.support.board_calibration import run_board_calibration

    if not args.bag:
        raise TlessbotError('--board needs --bag BAG (a recording of the board on the table)')
    args.bag, args.config = Path(args.bag), config
    return run_board_calibration(args)
