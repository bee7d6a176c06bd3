"""Board calibration accuracy: simulated moved rigs recovered from a ChArUco board.

For each of ``--rigs`` rigs, config/cell.yaml's two cameras are moved by up to ``--max-offset-m``
and turned by up to ``--max-angle-deg`` (rig 0 by exactly both, the others by random amounts up
to them; seeded), written as a cell YAML, simulated with the board on the table
(``tlessbot simulate --board``), and calibrated from the bag against config/cell.yaml as the
prior (``tlessbot calibrate --board``). Prints per rig and camera the error of the measured
pose (mm, degrees), the top <-> side transform's error, the fit's own 1-sigma, the time per
image (detection and fit) and of the whole calibration (with reading the bag and the one-off
imports), as a Markdown table; ``--out`` keeps the YAMLs and bags.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', required=True, type=Path, help='folder of obj_NN models')
    parser.add_argument('--out', type=Path, help='keep the rig YAMLs and bags here')
    parser.add_argument('--rigs', type=int, default=4, help='moved rigs (default 4)')
    parser.add_argument('--frames', type=int, default=5, help='frames per bag (default 5)')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--parts-max', type=int, default=0,
                        help='parts on the table and board (default 0: the board alone)')
    parser.add_argument('--max-offset-m', type=float, default=0.05)
    parser.add_argument('--max-angle-deg', type=float, default=15.0)


def moved_pose(T_world_camera: np.ndarray, rng: np.random.Generator, *, offset_m: float,
               angle_deg: float) -> np.ndarray:
    """``T_world_camera`` moved by ``offset_m`` in a random direction and turned by
    ``angle_deg`` about a random axis through its centre."""
    from tlessbot_ros.core.common import rotation_about_axis

    T = np.array(T_world_camera, dtype=np.float64)
    direction = rng.normal(size=3)
    T[:3, 3] += offset_m * direction / np.linalg.norm(direction)
    T[:3, :3] = rotation_about_axis(rng.normal(size=3), np.radians(angle_deg)) @ T[:3, :3]
    return T


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.core.calibrate import BoardSpec
    from tlessbot_ros.core.common import CameraMount, Rig
    from tlessbot_ros.errors import TlessbotError
    from tlessbot_ros.io.config import default_config_path
    from tlessbot_ros.tools.cli import main
    from tlessbot_ros.tools.support.board_calibration import (
        calibrate_with_board,
        rig_offsets,
    )
    from tlessbot_ros.tools.support.rig import load_rig, write_rig

    if args.rigs < 1 or args.frames < 1 or args.parts_max < 0:
        raise TlessbotError('--rigs and --frames must be at least 1, --parts-max at least 0')
    work = args.out or Path(tempfile.mkdtemp(prefix='bench_board_'))
    work.mkdir(parents=True, exist_ok=True)
    cell = default_config_path()
    prior = load_rig(cell)
    board = BoardSpec()
    rng = np.random.default_rng(args.seed)
    rows, worst = [], np.zeros(4)
    for k in range(args.rigs):
        cameras = {}
        for name, cam in prior.cameras.items():
            scale = (1.0, 1.0) if k == 0 else rng.uniform(0.0, 1.0, 2)
            T = moved_pose(cam.T_world_camera, rng, offset_m=scale[0] * args.max_offset_m,
                           angle_deg=scale[1] * args.max_angle_deg)
            cameras[name] = CameraMount(name, cam.intrinsics, T)
        config = work / f'rig_{k}.yaml'
        write_rig(cell, Rig(cameras=cameras, world_frame=prior.world_frame), config)
        truth = load_rig(config)  # the rig as the YAML holds it (rounded to 1 µm)
        moved, _ = rig_offsets(truth, prior)
        bag = work / f'bag_{k}'
        command = ['simulate', '--models', str(args.models), '--bag', str(bag), '--frames',
                   str(args.frames), '--seed', str(args.seed + k), '--config', str(config),
                   '--board', '--parts-min', str(min(1, args.parts_max)), '--parts-max',
                   str(args.parts_max), '--cloud-stride', '8', '--no-progress']
        if args.parts_max == 0:
            command += ['--ids', '5']  # no part is drawn: load one model only
        print('tlessbot ' + ' '.join(command))
        if main(command) != 0:
            raise TlessbotError(f'simulating rig {k} failed')
        start = time.perf_counter()
        measured, report = calibrate_with_board(bag, prior, board)
        wall_s = time.perf_counter() - start
        errors, pair = rig_offsets(measured, truth)
        for name, (mm, deg) in errors.items():
            cam = report.cameras[name]
            rows.append(f'| {k} | {name} | {moved[name][0]:.0f} mm, {moved[name][1]:.1f}° | '
                        f'{cam.corners} | {mm:.2f} | {deg:.3f} | {cam.sigma_mm:.2f} | '
                        f'{cam.sigma_deg:.3f} | {report.ms_per_image:.0f} | {wall_s:.1f} |')
            worst[:2] = np.maximum(worst[:2], (mm, deg))
        assert pair is not None
        rows.append(f'| {k} | top <-> side | | | {pair[0]:.2f} | {pair[1]:.3f} | | | | |')
        worst[2:] = np.maximum(worst[2:], pair)
    print()
    print('| rig | camera | moved by | corners | error mm | error ° | 1σ mm | 1σ ° | '
          'ms per image | whole run s |')
    print('|---|---|---|---|---|---|---|---|---|---|')
    print('\n'.join(rows))
    print(f'\nworst: camera {worst[0]:.2f} mm, {worst[1]:.3f}°; top <-> side {worst[2]:.2f} mm, '
          f'{worst[3]:.3f}° (goal 5 mm, 0.5°)')
    return 0
