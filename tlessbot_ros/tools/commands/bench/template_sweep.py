"""Template sweep: pose recall and time against the number of templates (paper Fig. 13/14, Tab. 2).

    tlessbot bench template-sweep --models ../shared/data/tless_models_cad_stl --out sweep/
    tlessbot bench template-sweep --models ... --ids 5 11 --views 2 6 12 18 --objects-per-class 5

For every template count the database is rebuilt (N turntable views, 360°/N apart) and the same
simulated side-view objects (ground-truth mask and class) are scored with (a) the paper's
pipeline (FPFH + RANSAC against every template, best by fitness, no refinement) and (b) ours
(table-plane search, bounded RANSAC fallback over the templates). Writes
``template_sweep.md`` and ``template_sweep.png`` (recall at 5 cm / 5° and 1 cm / 5°, median ms)
to --out. Defaults (the paper's objects 5 and 11, 3 objects each, 9 counts) take a few minutes.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', type=Path, required=True, help='folder of CAD models (mm)')
    parser.add_argument('--out', type=Path, required=True, help='folder for the PNG and .md')
    parser.add_argument('--ids', type=int, nargs='+', default=[5, 11],
                        help="object ids (default: the paper's 5 and 11)")
    parser.add_argument('--views', type=int, nargs='+', default=[2, 4, 6, 8, 10, 12, 14, 16, 18],
                        help='template counts, 2-18')
    parser.add_argument('--objects-per-class', type=int, default=3)
    parser.add_argument('--noise-scale', type=float, default=1.0)
    parser.add_argument('--min-visib', type=float, default=0.3)
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--max-frames', type=int, default=400)
    parser.add_argument('--skip-baseline', action='store_true', help='run (b) only')


def run(args: argparse.Namespace) -> int:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from tlessbot_ros.core.pose import PoseEstimator, PoseParams
    from tlessbot_ros.errors import TlessbotError
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.tools.support.models_info import packaged_symmetries
    from tlessbot_ros.tools.support.pose_bench import (
        SymmetryAwareScorer,
        collect_objects,
        score_methods,
        template_database,
        warm,
    )

    if any(not 2 <= v <= 18 for v in args.views):
        raise TlessbotError('--views must lie in 2..18')
    models = load_models(args.models, ids=args.ids)
    objects = collect_objects(models, per_class=args.objects_per_class,
                              noise_scale=args.noise_scale, min_visib=args.min_visib,
                              seed=args.seed, max_frames=args.max_frames)
    if not objects:
        raise TlessbotError('no simulated objects to score; raise --max-frames')
    symmetries = packaged_symmetries()
    scorers = {i: SymmetryAwareScorer(m, symmetries.get(i)) for i, m in models.items()}
    rows = []
    for views in sorted(set(args.views)):
        t0 = time.perf_counter()
        db = template_database(models, views=views)
        build_s = time.perf_counter() - t0
        methods = {'(b) ours': PoseEstimator(db, params=PoseParams())}
        if not args.skip_baseline:
            methods['(a) paper'] = PoseEstimator(
                db, params=PoseParams(method='ransac', refine=False))
        warm(db, models)
        results = score_methods(methods, objects, scorers, with_vsd=False,
                                desc=f'{views} templates')
        for name, scores in results.items():
            a = scores['all']
            rows.append((views, name, float(np.median(a.ms)), float(np.mean(a.ok5)),
                         float(np.mean(a.ok1)), float(np.mean(a.adds)), len(a.ms), build_s))

    args.out.mkdir(parents=True, exist_ok=True)
    ids = ' '.join(f'obj_{i:02d}' for i in sorted(models))
    lines = [f'## Template sweep: {ids}, {len(objects)} side-view objects, noise '
             f'x{args.noise_scale}, seed {args.seed}', '',
             '| templates | method | median ms/object | recall 5cm/5° | recall 1cm/5° '
             '| ADD-S<0.1d | n | build s |', '|---' * 8 + '|']
    lines += [f'| {v} | {name} | {ms:.1f} | {r5:.3f} | {r1:.3f} | {ad:.3f} | {n} | {b:.1f} |'
              for v, name, ms, r5, r1, ad, n, b in rows]
    (args.out / 'template_sweep.md').write_text('\n'.join(lines) + '\n', encoding='utf-8')

    fig, (ax_r, ax_t) = plt.subplots(1, 2, figsize=(10, 4))
    for name in dict.fromkeys(r[1] for r in rows):
        sel = [r for r in rows if r[1] == name]
        x = [r[0] for r in sel]
        ax_r.plot(x, [r[3] for r in sel], 'o-', label=f'{name} 5cm/5°')
        ax_r.plot(x, [r[4] for r in sel], 's--', label=f'{name} 1cm/5°')
        ax_t.plot(x, [r[2] for r in sel], 'o-', label=name)
    ax_r.set(xlabel='templates', ylabel='recall', ylim=(0, 1.05), title='Recall (Fig. 13)')
    ax_t.set(xlabel='templates', ylabel='median ms / object', yscale='log',
             title='Time (Fig. 14)')
    for ax in (ax_r, ax_t):
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out / 'template_sweep.png', dpi=120)
    plt.close(fig)
    print('\n'.join(lines))
    print(f'-> {args.out / "template_sweep.md"}, {args.out / "template_sweep.png"}')
    return 0
