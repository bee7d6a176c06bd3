"""Simulator speed: two-view frames per second with a per-stage breakdown.

Renders ``--frames`` two-view frames of exactly ``--parts`` parts (default 100 frames of 5
parts at 640x480, the issue's target: <= 60 s on the 2-core box) and prints the total, ms per
frame and the split into scene sampling, ray casting, shading, noise and ground truth.
Model loading and the per-model caches (resting poses, hulls) are timed separately.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', required=True, type=Path, help='folder of obj_NN models')
    parser.add_argument('--frames', type=int, default=100)
    parser.add_argument('--parts', type=int, default=5)
    parser.add_argument('--width', type=int, default=640)
    parser.add_argument('--height', type=int, default=480)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--ids', type=int, nargs='+', help='object ids (default: all)')
    parser.add_argument('--no-progress', action='store_true')


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from tlessbot_ros.core.common import default_rig
    from tlessbot_ros.errors import TlessbotError
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.simulator import SimParams, Simulator

    if args.frames < 1 or args.parts < 1:
        raise TlessbotError('--frames and --parts must be at least 1')
    t0 = time.perf_counter()
    models = load_models(args.models, args.ids)
    t_load = time.perf_counter() - t0
    sim = Simulator(models, rig=default_rig(args.width, args.height),
                    params=SimParams(parts_min=args.parts, parts_max=args.parts), seed=args.seed)
    t0 = time.perf_counter()
    sim.prepare(progress=not args.no_progress)  # resting poses and hulls of every model
    t_warm = time.perf_counter() - t0
    sim.timings.clear()
    parts = 0
    c0 = time.process_time()
    t0 = time.perf_counter()
    for index in tqdm(range(args.frames), desc='bench sim', unit='frame',
                      disable=args.no_progress):
        parts += len(sim.frame(index).objects)
    total = time.perf_counter() - t0
    cpu = time.process_time() - c0
    n = args.frames
    views = len(sim.rig.cameras)
    print(f'simulator: {n} frames x {views} views at {args.width}x{args.height}, '
          f'{parts / n:.2f} parts/frame, {len(models)} models')
    print(f'  model loading {t_load:.2f} s, resting poses + hulls {t_warm:.2f} s')
    print(f'  total {total:.2f} s = {1000 * total / n:.0f} ms/frame '
          f'({1000 * total / (n * views):.0f} ms/view)')
    load = os.getloadavg()[0] if hasattr(os, 'getloadavg') else float('nan')
    print(f'  CPU time {cpu:.2f} s = {1000 * cpu / n:.0f} ms/frame (all threads); '
          f'load average {load:.1f} on {os.cpu_count()} cores')
    print('  | stage | ms/frame | share |')
    print('  |---|---:|---:|')
    accounted = sum(sim.timings.values())
    for stage in ('scene', 'raycast', 'shading', 'noise', 'gt'):
        value = sim.timings.get(stage, 0.0)
        print(f'  | {stage} | {1000 * value / n:.1f} | {100 * value / total:.0f} % |')
    other = total - accounted
    print(f'  | other | {1000 * other / n:.1f} | {100 * other / total:.0f} % |')
    return 0
