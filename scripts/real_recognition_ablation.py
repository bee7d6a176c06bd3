"""Which training change buys what on real images: CAD-only classifiers scored on a real BOP set.

  PYTHONPATH=. python scripts/real_recognition_ablation.py \\
      --dataset ../shared/data/sygrid_real_d435i --out reports/real_ablation

Each variant is ``tlessbot train --models <dataset>/models <args>`` followed by
``tlessbot evaluate --oracle boxes`` (ground-truth boxes, the classifier alone; the pose stage
on the frames with depth). Writes ``ablation.md`` (top-1 overall and per part, training time)
and ``ablation.png`` into --out; models and evaluation folders stay there. Variants that differ
only in ``--seed`` are summed up over their seeds in ``seeds.md`` and ``seeds.png`` (the
classifier's spread over training seeds is as large as most single changes).
"""
from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import time
from pathlib import Path

from tlessbot_ros.tools.support.report import cell

# The clutter variants below were measured at 2 crops a view (``--copies 2``), the recipe's
# default before the crops sweep at the end; they keep it so that a rerun measures the same.
TWO = ['--copies', '2']
VARIANTS = (
    ('turntable, paper features (before)', ['--recipe', 'turntable', '--features', 'paper']),
    ('turntable, ours (before: the old default)', ['--recipe', 'turntable']),
    ('+ clutter & box crops, no camera response, paper', [
        '--features', 'paper', '--no-box-size', '--clutter-param', 'photometric=false', *TWO]),
    ('+ random camera response, paper', ['--features', 'paper', '--no-box-size', *TWO]),
    ('+ box angular size, paper', ['--features', 'paper', *TWO]),
    ('+ depth shape features with dropout (clutter)', [*TWO]),
    ('clutter without neighbours', ['--clutter-param', 'neighbours=0,0', *TWO]),
    ('clutter + background class (15 %)', ['--clutter-param', 'background_share=0.15', *TWO]),
    ('clutter, seed 1', ['--seed', '1', *TWO]),
    ('clutter, perceptron', ['--classifier', 'perceptron', *TWO]),
    ('clutter, pa1', ['--classifier', 'pa1', *TWO]),
    ('clutter, pa2', ['--classifier', 'pa2', *TWO]),
    ('clutter, seed 2', ['--seed', '2', *TWO]),
    ('clutter + half the views on smoothed depth', ['--smoothed-share', '0.5', *TWO]),
    ('clutter + half the views on smoothed depth, seed 1', ['--smoothed-share', '0.5',
                                                            '--seed', '1', *TWO]),
    ('clutter + half the views on smoothed depth, seed 2', ['--smoothed-share', '0.5',
                                                            '--seed', '2', *TWO]),
    ('clutter + every view on smoothed depth', ['--smoothed-share', '1', *TWO]),
    ('clutter, seed 3', ['--seed', '3', *TWO]),
    ('clutter, seed 4', ['--seed', '4', *TWO]),
    ('clutter + half the views on smoothed depth, seed 3', ['--smoothed-share', '0.5',
                                                            '--seed', '3', *TWO]),
    ('clutter + half the views on smoothed depth, seed 4', ['--smoothed-share', '0.5',
                                                            '--seed', '4', *TWO]),
    *((f'clutter, 6 crops a view, seed {seed}', ['--copies', '6', '--seed', str(seed)])
      for seed in range(5)),
    *((f'clutter, averaged SGD, seed {seed}', ['--average', '--seed', str(seed), *TWO])
      for seed in range(5)),
    *((f'clutter, {copies} crops a view, seed {seed}', ['--copies', str(copies),
                                                        '--seed', str(seed)])
      for copies in (4, 10, 16) for seed in range(5)),
)


def _cli(*args: str) -> list[str]:
    return [sys.executable, '-m', 'tlessbot_ros.tools.cli', *args]


def run_variant(index: int, args: list[str], dataset: Path, out: Path) -> dict:
    folder = out / f'v{index:02d}'
    folder.mkdir(parents=True, exist_ok=True)
    model = folder / 'classifier.npz'
    started = time.perf_counter()
    subprocess.run(_cli('train', '--models', str(dataset / 'models'), '--out', str(model),
                        *args), check=True, stdout=subprocess.DEVNULL)
    train_s = time.perf_counter() - started
    templates = out / 'templates.npz'
    if not templates.is_file():
        subprocess.run(_cli('templates', '--models', str(dataset / 'models'), '--out',
                            str(templates)), check=True, stdout=subprocess.DEVNULL)
    subprocess.run(_cli('evaluate', '--dataset', str(dataset), '--models',
                        str(dataset / 'models'), '--oracle', 'boxes', '--classifier', str(model),
                        '--templates', str(templates), '--out', str(folder / 'eval')),
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    report = json.loads((folder / 'eval' / 'report.json').read_text())
    return {'train_s': train_s, **report['recognition']}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True)
    parser.add_argument('--out', type=Path, default=Path('reports/real_ablation'))
    parser.add_argument('--only', type=int, nargs='+', help='variant indices to run')
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    results_path = args.out / 'ablation.json'
    results = json.loads(results_path.read_text()) if results_path.is_file() else {}
    for index, (name, extra) in enumerate(VARIANTS):
        if args.only and index not in args.only:
            continue
        print(f'[{index + 1}/{len(VARIANTS)}] {name}', flush=True)
        results[name] = {'args': extra, **run_variant(index, extra, args.dataset, args.out)}
        results_path.write_text(json.dumps(results, indent=1) + '\n')
    write_table(results, args.out)
    write_seed_table(results, args.out)
    return 0


def recipe_of(name: str) -> str:
    """A variant's name without its training seed (seed 0 where it names none)."""
    name = name.replace('+ depth shape features with dropout (clutter)', 'clutter')
    return re.sub(r',? seed \d+$', '', name)


def write_seed_table(results: dict, out: Path) -> None:
    """``seeds.md`` and ``seeds.png``: per recipe run with two seeds or more, top-1 on the
    real boxes over its seeds (mean, lowest, highest) and the mean after the pose stage."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    groups: dict[str, list[dict]] = {}
    for name, _ in VARIANTS:
        if name in results:
            groups.setdefault(recipe_of(name), []).append(results[name])
    groups = {recipe: runs for recipe, runs in groups.items() if len(runs) >= 2}
    lines = ['| recipe | seeds | top-1 mean | lowest | highest | after pose stage, mean |',
             '|---|---|---|---|---|---|']
    for recipe, runs in groups.items():
        top1 = [run['top1_classifier'] for run in runs]
        after = [run['top1_after_pose'] for run in runs]
        lines.append(f'| {recipe} | {len(runs)} | {sum(top1) / len(top1):.3f} | {min(top1):.3f} '
                     f'| {max(top1):.3f} | {sum(after) / len(after):.3f} |')
    (out / 'seeds.md').write_text('\n'.join(lines) + '\n', encoding='utf-8')
    print('\n'.join(lines))
    if not groups:
        return
    fig, ax = plt.subplots(figsize=(9, 0.5 * len(groups) + 1.2))
    for row, runs in enumerate(groups.values()):
        top1 = [run['top1_classifier'] for run in runs]
        ax.plot(top1, [row] * len(top1), 'o', color='tab:blue', alpha=0.6)
        ax.plot([sum(top1) / len(top1)], [row], '|', color='black', markersize=18)
    ax.set_yticks(range(len(groups)), list(groups), fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel('top-1 on real ground-truth boxes, one dot a training seed (bar: mean)')
    fig.tight_layout()
    fig.savefig(out / 'seeds.png', dpi=110)
    plt.close(fig)


def write_table(results: dict, out: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    names = [name for name, _ in VARIANTS if name in results]
    parts = sorted({p for r in results.values() for p in r['per_part']}, key=int)
    lines = ['| variant | train args | top-1 | after pose stage | '
             + ' | '.join(f'obj_{int(p):02d}' for p in parts) + ' | train s |',
             '|---' * (5 + len(parts)) + '|']
    for name in names:
        r = results[name]
        cells = [f'{r["per_part"][p]["top1_classifier"]:.2f}' for p in parts]
        lines.append(f'| {name} | `{" ".join(r["args"]) or "(defaults)"}` | '
                     f'{cell(r["top1_classifier"])} | {cell(r["top1_after_pose"])} | '
                     + ' | '.join(cells) + f' | {r["train_s"]:.0f} |')
    (out / 'ablation.md').write_text('\n'.join(lines) + '\n', encoding='utf-8')
    print('\n'.join(lines))
    fig, ax = plt.subplots(figsize=(9, 0.45 * len(names) + 1.2))
    ax.barh(range(len(names)), [results[n]['top1_classifier'] for n in names], color='tab:blue')
    ax.axvline(0.70, color='tab:red', linestyle='--', label='goal 0.70')
    ax.axvline(0.20, color='grey', linestyle=':', label='chance (5 parts)')
    ax.set_yticks(range(len(names)), names, fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 1)
    ax.set_xlabel('top-1 on real ground-truth boxes (classifier alone)')
    ax.legend(loc='lower right', fontsize=8)
    fig.tight_layout()
    fig.savefig(out / 'ablation.png', dpi=110)
    plt.close(fig)


if __name__ == '__main__':
    sys.exit(main())
