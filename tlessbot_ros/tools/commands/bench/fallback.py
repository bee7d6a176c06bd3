"""Fallback: the bounded 'views' fallback against the former FPFH + RANSAC one, same parts.

    tlessbot bench fallback --models ../shared/data/tless_models_cad_stl --objects-per-class 5
    tlessbot bench fallback --models ... --lean-prob 1 --leaning-only --seed 23

Side view, ground-truth visible mask and class given (as ``bench pose``); every method runs in
this process on the same ROI clouds, one part after the other (interleaved), so the host's
load touches them alike. Methods (``PoseParams`` in brackets):

* views, forced (``force_fallback``): every part goes straight to the new fallback;
* templates, no table frame (``fallback_method=templates``, no ``T_world_camera``): the path
  every part took without extrinsics before (FPFH + RANSAC against all templates);
* table + views / table + templates, forced (``fallback_fitness=1.01``): the table path runs,
  then the fallback, and the best of both is kept;
* table, default (views below ``fallback_fitness``, 0.85), views below 0.7, templates below 0.7
  (the former default): the fallback only for a poor table fit; their rows "sent to the
  fallback" count only those parts.

Printed: recall within 5 cm / 5° and 1 cm / 5° (symmetry-aware), p50 / p95 / max ms per part,
on all parts and, with ``--lean-prob``, on the leaning ones (tilted out of every stable pose).
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', type=Path, required=True, help='folder of CAD models (mm)')
    parser.add_argument('--templates', type=Path,
                        help='template database (default: the shipped one)')
    parser.add_argument('--objects-per-class', type=int, default=5,
                        help='side-view parts scored per class (default 5)')
    parser.add_argument('--ids', type=int, nargs='+', help='only these object ids')
    parser.add_argument('--lean-prob', type=float, default=0.0,
                        help='chance that a simulated part leans (simulate --lean-prob)')
    parser.add_argument('--leaning-only', action='store_true',
                        help='score only the leaning parts (with --lean-prob)')
    parser.add_argument('--noise-scale', type=float, default=1.0)
    parser.add_argument('--min-visib', type=float, default=0.3)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--max-frames', type=int, default=400, help='simulated frames at most')
    parser.add_argument('--skip-slow', action='store_true',
                        help='skip "templates, no table frame" (1-3 s a part)')
    parser.add_argument('--pose-param', action='append', metavar='NAME=VALUE',
                        help='override a PoseParams field of every method (repeatable)')
    parser.add_argument('--markdown', type=Path, help='also write the tables to this .md file')


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.core.pose import PoseEstimator, PoseParams
    from tlessbot_ros.data import DEFAULT_TEMPLATES
    from tlessbot_ros.errors import TlessbotError
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.tools.support.models_info import packaged_symmetries
    from tlessbot_ros.tools.support.overrides import apply_overrides
    from tlessbot_ros.tools.support.pose_bench import (
        SymmetryAwareScorer,
        collect_objects,
        template_database,
    )

    if not 0.0 <= args.lean_prob <= 1.0:
        raise TlessbotError('--lean-prob must be in [0, 1]')
    db = template_database({}, views=12, path=args.templates or DEFAULT_TEMPLATES)
    ids = sorted(set(args.ids or db.objects) & set(db.objects))
    if not ids:
        raise TlessbotError('none of --ids has templates')
    models = load_models(args.models, ids=ids)
    objects = collect_objects(models, per_class=args.objects_per_class,
                              noise_scale=args.noise_scale, min_visib=args.min_visib,
                              seed=args.seed, max_frames=args.max_frames,
                              lean_prob=args.lean_prob)
    leaning = [_leaning(models[o[0]], o[3].T_world_camera @ o[2]) for o in objects]
    if args.leaning_only:
        objects = [o for o, lean in zip(objects, leaning) if lean]
        leaning = [True] * len(objects)
    if not objects:
        raise TlessbotError('no simulated parts to score; raise --max-frames or --lean-prob')
    symmetries = packaged_symmetries()
    scorers = {i: SymmetryAwareScorer(models[i], symmetries.get(i)) for i in models}

    def params(**changes) -> PoseParams:
        return apply_overrides(PoseParams(**changes), args.pose_param)
    before = {'fallback_method': 'templates', 'fallback_budget_ms': 60.0}
    methods = {  # name -> (estimator, with the table frame)
        'views, forced': (params(force_fallback=True), True),
        'templates, no table frame (before)': (params(**before), False),
        'table + views, forced': (params(fallback_fitness=1.01), True),
        'table + templates, forced (before)': (params(fallback_fitness=1.01, **before), True),
        f'table, default (views below {PoseParams().fallback_fitness})': (params(), True),
        'table, views below 0.7': (params(fallback_fitness=0.7), True),
        'table, templates below 0.7 (before)': (params(fallback_fitness=0.7, **before), True),
    }
    if args.skip_slow:
        del methods['templates, no table frame (before)']
    estimators = {name: PoseEstimator(db, params=p) for name, (p, _) in methods.items()}
    for estimator in estimators.values():
        estimator.warm_up(ids)
    rows: dict[str, list[tuple[bool, bool, float, bool]]] = {name: [] for name in methods}
    load_before = os.getloadavg()
    from tqdm import tqdm
    for (obj_id, points, T_gt, view, _), lean in tqdm(list(zip(objects, leaning)),
                                                      desc='parts', unit='part'):
        for name, (_, with_table) in methods.items():
            start = time.perf_counter()
            result = estimators[name].estimate(
                points, obj_id, T_world_camera=view.T_world_camera if with_table else None)
            ms = 1e3 * (time.perf_counter() - start)
            T = result.best.T_camera_object if result.best is not None else np.eye(4)
            error = scorers[obj_id].error(T, T_gt)
            sent = 'fallback' in result.timings_ms or 'ransac' in result.timings_ms
            rows[name].append((error.translation_m < 0.05 and error.rotation_deg < 5.0,
                               error.translation_m < 0.01 and error.rotation_deg < 5.0, ms,
                               sent, lean))
    load_after = os.getloadavg()
    lines = _tables(rows, args, load_before, load_after, any(leaning))
    print('\n'.join(lines))
    if args.markdown:
        args.markdown.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    return 0


def _leaning(model, T_world_object: np.ndarray, *, tolerance_deg: float = 5.0) -> bool:
    """True when the part rests in none of its stable poses (its up axis differs from every
    stable pose's by more than ``tolerance_deg``)."""
    from tlessbot_ros.io.models import stable_poses
    up = T_world_object[:3, :3].T @ np.array([0.0, 0.0, 1.0])      # world up, object frame
    ups = np.array([p.T_table_object[:3, :3].T @ np.array([0.0, 0.0, 1.0])
                    for p in stable_poses(model)])
    return bool(np.degrees(np.arccos(np.clip(ups @ up, -1.0, 1.0))).min() > tolerance_deg)


def _row(name: str, items: list) -> str:
    if not items:
        return f'| {name} | 0 | n/a | n/a | n/a | n/a | n/a |'
    ok5, ok1, ms = (np.array([r[i] for r in items], float) for i in range(3))
    return (f'| {name} | {len(items)} | {ok5.mean():.3f} | {ok1.mean():.3f} | '
            f'{np.median(ms):.1f} | {np.percentile(ms, 95):.1f} | {ms.max():.1f} |')


def _tables(rows: dict, args: argparse.Namespace, load_before, load_after,
            with_leaning: bool) -> list[str]:
    head = ['| method | parts | 5 cm / 5° | 1 cm / 5° | p50 ms | p95 ms | max ms |',
            '|---|---|---|---|---|---|---|']
    lines = [f'## bench fallback: seed {args.seed}, lean prob {args.lean_prob}'
             f'{" (leaning parts only)" if args.leaning_only else ""}, noise x'
             f'{args.noise_scale}, min visib {args.min_visib}', '', '### all parts', ''] + head
    lines += [_row(name, items) for name, items in rows.items()]
    if with_leaning and not args.leaning_only:
        lines += ['', '### leaning parts', ''] + head
        lines += [_row(name, [r for r in items if r[4]]) for name, items in rows.items()]
    lines += ['', '### parts the table path sent to its fallback (fitness below '
                  'fallback_fitness)', ''] + head
    for name in list(rows)[-3:]:
        lines.append(_row(name, [r for r in rows[name] if r[3]]))
    new, old = rows['views, forced'], rows.get('templates, no table frame (before)')
    if old:
        ms_new = np.array([r[2] for r in new])
        ms_old = np.array([r[2] for r in old])
        lines += ['', f'time ratio, templates (before) / views, forced: p50 '
                      f'{np.median(ms_old) / np.median(ms_new):.1f}x, p95 '
                      f'{np.percentile(ms_old, 95) / np.percentile(ms_new, 95):.1f}x']
    lines += ['', f'load average (1/5/15 min) before {load_before[0]:.2f}/{load_before[1]:.2f}/'
                  f'{load_before[2]:.2f}, after {load_after[0]:.2f}/{load_after[1]:.2f}/'
                  f'{load_after[2]:.2f}; {os.cpu_count()} CPUs']
    return lines
