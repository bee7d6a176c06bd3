"""Which training change buys what on real images: CAD-only classifiers scored on a real BOP set.

  PYTHONPATH=. python scripts/real_recognition_ablation.py \\
      --dataset ../shared/data/sygrid_real_d435i --out reports/real_ablation

Each variant is ``tlessbot train --models <dataset>/models <args>`` followed by
``tlessbot evaluate --oracle boxes`` (ground-truth boxes, the classifier alone; the pose stage
on the frames with depth). Writes ``ablation.md`` (top-1 overall and per part, training time)
and ``ablation.png`` into --out; models and evaluation folders stay there.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

from tlessbot_ros.tools.support.report import cell

VARIANTS = (
    ('turntable, paper features (before)', ['--recipe', 'turntable', '--features', 'paper']),
    ('turntable, ours (before: the old default)', ['--recipe', 'turntable']),
    ('+ clutter & box crops, no camera response, paper', [
        '--features', 'paper', '--no-box-size', '--clutter-param', 'photometric=false']),
    ('+ random camera response, paper', ['--features', 'paper', '--no-box-size']),
    ('+ box angular size, paper', ['--features', 'paper']),
    ('+ depth shape features with dropout (default)', []),
    ('default without neighbours', ['--clutter-param', 'neighbours=0,0']),
    ('default + background class (15 %)', ['--clutter-param', 'background_share=0.15']),
    ('default, seed 1', ['--seed', '1']),
    ('default, perceptron', ['--classifier', 'perceptron']),
    ('default, pa1', ['--classifier', 'pa1']),
    ('default, pa2', ['--classifier', 'pa2']),
    ('default, seed 2', ['--seed', '2']),
    ('default + half the views on smoothed depth', ['--smoothed-share', '0.5']),
    ('default + half the views on smoothed depth, seed 1', ['--smoothed-share', '0.5',
                                                            '--seed', '1']),
    ('default + half the views on smoothed depth, seed 2', ['--smoothed-share', '0.5',
                                                            '--seed', '2']),
    ('default + every view on smoothed depth', ['--smoothed-share', '1']),
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
    return 0


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
