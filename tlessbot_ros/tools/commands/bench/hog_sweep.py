"""Accuracy and training time against HOG cell size and bins for the four learners (Fig. 10).

Crops are rendered and normalised once (turntable for training, simulated two-view scenes with
another seed for testing); then for every cell size × bins the HOG is recomputed and SGD,
Perceptron, PA-I and PA-II are trained and scored. The default run is small (coarse turntable,
few scenes) so that it finishes in a few minutes on two cores:

    tlessbot bench hog_sweep --models ../shared/data/tless_models_cad_stl --out reports/hog_sweep

Writes <out>/hog_sweep.md and <out>/hog_sweep.png.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', type=Path, required=True, help='CAD model folder')
    parser.add_argument('--ids', type=int, nargs='+', help='only these objects (default all)')
    parser.add_argument('--cells', type=int, nargs='+', default=[4, 6, 10, 15],
                        help='cell sizes in px (must divide 60)')
    parser.add_argument('--bins', type=int, nargs='+', default=[2, 3, 4, 5])
    parser.add_argument('--steps-deg', type=float, default=20.0, help='turntable step')
    parser.add_argument('--augmentations', type=int, default=1)
    parser.add_argument('--scenes', type=int, default=12, help='simulated test frames')
    parser.add_argument('--seed', type=int, default=0, help='training seed (test: seed + 1000)')
    parser.add_argument('--epochs', type=int, default=5)
    parser.add_argument('--out', type=Path, default=Path('reports/hog_sweep'))


def _crops(models_dir: Path, ids: list[int] | None, *, steps_deg: float, augmentations: int,
           scenes: int, seed: int):
    from tqdm import tqdm

    from tlessbot_ros.core.recognise import normalise_crop
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.simulator import Simulator
    from tlessbot_ros.sim.turntable import Turntable, TurntableParams

    models = load_models(models_dir, ids)
    table = Turntable(models, params=TurntableParams(step_deg=steps_deg,
                                                     augmentations=augmentations),
                      seed=seed)
    train, train_y = [], []
    for sample in tqdm(table.samples(), total=len(table), desc='turntable', unit='crop'):
        train.append(normalise_crop(sample.rgb, mask=sample.mask))
        train_y.append(sample.obj_id)
    simulator = Simulator(models, seed=seed + 1000)
    test, test_y = [], []
    for index in tqdm(range(scenes), desc='simulate', unit='frame'):
        for view in simulator.frame(index).views.values():
            for gt in view.gt:
                if gt.px_count_visib >= 100:
                    test.append(normalise_crop(view.rgb, mask=gt.mask_visib))
                    test_y.append(gt.obj_id)
    return np.array(train), np.array(train_y), np.array(test), np.array(test_y)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from tlessbot_ros.core.recognise import (
        KINDS,
        ClassifierParams,
        HogParams,
        hog_features,
        train_classifier,
    )
    from tlessbot_ros.errors import TlessbotError

    for cell in args.cells:
        if 60 % cell or cell < 2 or cell > 30:
            raise TlessbotError(f'cell size {cell} does not divide the 60 px crop')
    train, train_y, test, test_y = _crops(args.models, args.ids, steps_deg=args.steps_deg,
                                          augmentations=args.augmentations,
                                          scenes=args.scenes, seed=args.seed)
    rows = []  # (cell, bins, kind, dim, accuracy, train_s)
    grid = [(c, b) for c in args.cells for b in args.bins]
    for cell, bins in tqdm(grid, desc='sweep', unit='setting'):
        hog = HogParams(cell_px=cell, bins=bins)
        x_train = hog_features(train, params=hog)
        x_test = hog_features(test, params=hog)
        for kind in KINDS:
            t0 = time.perf_counter()
            model = train_classifier(x_train, train_y, hog_params=hog, seed=args.seed,
                                     params=ClassifierParams(kind=kind, epochs=args.epochs))
            train_s = time.perf_counter() - t0
            accuracy = float(np.mean(model.predict(x_test).class_ids == test_y))
            rows.append((cell, bins, kind, hog.feature_dim, accuracy, train_s))
    args.out.mkdir(parents=True, exist_ok=True)
    lines = ['# HOG sweep (paper Fig. 10)', '',
             f'Training: {len(train_y)} turntable crops ({args.steps_deg}° steps, '
             f'{args.augmentations} augmentations); test: {len(test_y)} crops from '
             f'{args.scenes} simulated frames (seed {args.seed + 1000}); '
             f'{len(np.unique(train_y))} objects, {args.epochs} epochs.', '',
             '| cell px | bins | dim | ' + ' | '.join(f'{k} acc % / train s' for k in KINDS)
             + ' |', '|---|---|---|' + '---|' * len(KINDS)]
    for cell, bins in grid:
        cells = [r for r in rows if r[0] == cell and r[1] == bins]
        lines.append(f'| {cell} | {bins} | {cells[0][3]} | ' + ' | '.join(
            f'{100 * r[4]:.1f} / {r[5]:.2f}' for r in cells) + ' |')
    best = max(rows, key=lambda r: r[4])
    lines += ['', f'Best: {best[2]} with cell {best[0]} px, {best[1]} bins: '
              f'{100 * best[4]:.1f} %.', '', '![sweep](hog_sweep.png)']
    _plot(args.out / 'hog_sweep.png', rows, args.cells, args.bins, KINDS)
    (args.out / 'hog_sweep.md').write_text('\n'.join(lines) + '\n', encoding='utf-8')
    print('\n'.join(lines))
    print(f'\nwrote {args.out / "hog_sweep.md"} and hog_sweep.png')
    return 0


def _plot(path: Path, rows, cells, bins_list, kinds) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, len(kinds), figsize=(4 * len(kinds), 6.5), sharex=True)
    for k, kind in enumerate(kinds):
        for bins in bins_list:
            sel = sorted((r for r in rows if r[2] == kind and r[1] == bins), key=lambda r: r[0])
            axes[0, k].plot([r[0] for r in sel], [100 * r[4] for r in sel], 'o-',
                            label=f'{bins} bins')
            axes[1, k].plot([r[0] for r in sel], [r[5] for r in sel], 'o-',
                            label=f'{bins} bins')
        axes[0, k].set_title(kind)
        axes[0, k].set_ylabel('top-1 accuracy %')
        axes[1, k].set_ylabel('training time s')
        axes[1, k].set_xlabel('HOG cell size px')
        axes[0, k].grid(alpha=0.3)
        axes[1, k].grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
