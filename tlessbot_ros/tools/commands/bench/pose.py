"""Pose: the paper's FPFH+RANSAC pipeline (a) against ours (b) on the same simulated objects.

    tlessbot bench pose --models ../shared/data/tless_models_cad_stl --objects-per-class 5
    tlessbot bench pose --models ... --noise-scale 2

Side view, ground-truth visible mask and class given (the paper's "GT BBOX + our pose" row).
(a) FPFH + RANSAC against each of the 12 templates with the Open3D tutorial's settings, best by
RANSAC fitness, no refinement; (b) ours (``PoseParams()``: table-plane search + ICP, RANSAC
fallback). Both run in this process on the same ROI clouds. Printed: median ms per object,
recall at 5 cm / 5° and 1 cm / 5° (symmetry-aware), ADD-S < 0.1 d recall and, when
``tlessbot_ros.core.metrics`` provides it, VSD < 0.3 recall; per object and overall.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--pose-param', action='append', metavar='NAME=VALUE',
                        help='override a PoseParams field of (b), e.g. icp_iterations=6 '
                             '(repeatable)')
    parser.add_argument('--models', type=Path, required=True, help='folder of CAD models (mm)')
    parser.add_argument('--objects-per-class', type=int, default=5,
                        help='side-view objects scored per class (default 5)')
    parser.add_argument('--noise-scale', type=float, default=1.0,
                        help='depth noise multiplier of the simulator (2: sigma x 2, more holes)')
    parser.add_argument('--ids', type=int, nargs='+', help='only these object ids')
    parser.add_argument('--views', type=int, default=12, help='templates per object (12)')
    parser.add_argument('--min-visib', type=float, default=0.3,
                        help='skip objects less visible than this (default 0.3)')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--max-frames', type=int, default=400, help='simulated frames at most')
    parser.add_argument('--skip-baseline', action='store_true', help='run (b) only')
    parser.add_argument('--markdown', type=Path, help='also write the tables to this .md file')
    parser.add_argument('--templates', type=Path,
                        help='use this template database (e.g. the shipped one) instead of '
                             'building one with --views')
    parser.add_argument('--no-vsd', action='store_true', help='skip VSD (faster)')
    parser.add_argument('--failures', action='store_true',
                        help='list the objects that miss 1 cm / 5°')


def run(args: argparse.Namespace) -> int:
    import os

    from tlessbot_ros.core.pose import PoseEstimator, PoseParams
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.tools.support.models_info import packaged_symmetries
    from tlessbot_ros.tools.support.overrides import apply_overrides
    from tlessbot_ros.tools.support.pose_bench import (
        SymmetryAwareScorer,
        collect_objects,
        score_methods,
        template_database,
        warm,
    )

    models = load_models(args.models, ids=args.ids)
    t0 = time.perf_counter()
    db = template_database(models, views=args.views, path=args.templates)
    print(f'templates: {time.perf_counter() - t0:.1f} s')
    objects = collect_objects(models, per_class=args.objects_per_class,
                              noise_scale=args.noise_scale, min_visib=args.min_visib,
                              seed=args.seed, max_frames=args.max_frames)
    symmetries = packaged_symmetries()
    scorers = {i: SymmetryAwareScorer(m, symmetries.get(i)) for i, m in models.items()}
    methods = {'(b) ours': PoseEstimator(db, params=apply_overrides(PoseParams(),
                                                                    args.pose_param))}
    if not args.skip_baseline:
        methods['(a) paper'] = PoseEstimator(db, params=PoseParams(method='ransac',
                                                                   refine=False))
    warm(db, models)
    load_before = os.getloadavg()
    results = score_methods(methods, objects, scorers, with_vsd=not args.no_vsd)
    load_after = os.getloadavg()
    lines = _tables(results, models, templates=args.templates, views=args.views,
                    noise_scale=args.noise_scale, min_visib=args.min_visib, seed=args.seed)
    lines += ['', f'load average (1/5/15 min) before {load_before[0]:.2f}/{load_before[1]:.2f}/'
                  f'{load_before[2]:.2f}, after {load_after[0]:.2f}/{load_after[1]:.2f}/'
                  f'{load_after[2]:.2f}; {os.cpu_count()} CPUs']
    print('\n'.join(lines))
    if args.failures:
        for name, scores in results.items():
            for obj_id, t_err, r_err, ms in scores['errors']:
                if not (t_err < 0.01 and r_err < 5.0):
                    print(f'{name} obj_{obj_id:02d}: {1e3 * t_err:.1f} mm, {r_err:.1f} deg, '
                          f'{ms:.0f} ms')
    if args.markdown:
        args.markdown.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    return 0


def _tables(results: dict, models: dict, *, templates: Path | None, views: int,
            noise_scale: float, min_visib: float, seed: int) -> list[str]:
    source = templates or f'{views} templates'
    head = ('| method | median ms/object | p95 ms | max ms | recall 5cm/5° | recall 1cm/5° '
            '| ADD-S<0.1d | VSD<0.3 | n |')
    lines = [f'## bench pose: noise x{noise_scale}, {source}, min visib {min_visib}, '
             f'seed {seed}', '', head, '|---' * 9 + '|']
    for name, scores in results.items():
        a = scores['all']
        row = a.row()
        extra = [f'{np.percentile(a.ms, 95):.1f}', f'{np.max(a.ms):.1f}'] if a.ms else ['n/a'] * 2
        lines.append('| ' + ' | '.join([name, row[0]] + extra + row[1:]) + ' |')
    if '(a) paper' in results:
        a, b = results['(a) paper']['all'], results['(b) ours']['all']
        lines += ['', f'speed-up (a)/(b) of the median time: '
                      f'{np.median(a.ms) / np.median(b.ms):.1f}x']
    cols = ('ms', '5cm/5°', '1cm/5°', 'ADD-S', 'VSD')
    lines += ['', '| object | ' + ' | '.join(f'{n} {c}' for n in results for c in cols) + ' |',
              '|---|' + '---|' * (len(cols) * len(results))]
    for obj_id in sorted(models):
        cells = []
        for name in results:
            s = results[name].get(obj_id)
            cells += s.row()[:5] if s and s.ms else ['n/a'] * 5
        lines.append(f'| obj_{obj_id:02d} | ' + ' | '.join(cells) + ' |')
    return lines
