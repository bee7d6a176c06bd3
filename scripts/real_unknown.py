"""Unknown stays unknown: background boxes and parts left out of training, on a real BOP set.

  PYTHONPATH=. python scripts/real_unknown.py --dataset ../shared/data/sygrid_real_d435i \\
      --out reports/real_unknown [--boxes-per-frame 20] [--leave-one-out]

A CAD-only classifier (``tlessbot train --models <dataset>/models``, defaults) names the
ground-truth boxes of the real frames and ``--boxes-per-frame`` random background boxes per
frame (sizes drawn from the ground-truth boxes; no box holds more than 30 % of any part's
box). For each reject threshold (a multiple of the model's ``margin_scale``, the median margin
on its training crops) the table gives top-1 on the parts (a rejected part counts wrong), the
parts called unknown, and the background boxes named as a part (false positives per frame).
With --leave-one-out, one model per part is trained without it and the left-out part's crops
are scored as unknown or not. Writes unknown.md and unknown.png into --out.
"""
from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import numpy as np

FRACTIONS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0)


def real_boxes(dataset: Path, per_frame: int, seed: int = 0):
    """[(rgb, K, part boxes, part ids, background boxes)] of every frame of the test split."""
    from tlessbot_ros.io.bop import read_split
    from tlessbot_ros.tools.support.eval_frames import background_boxes

    rng = np.random.default_rng(seed)
    frames = []
    for image in read_split(dataset, 'test', load_masks=False):
        parts = [(g.bbox_visib, g.obj_id) for g in image.gt
                 if g.bbox_visib is not None and (g.visib_fract or 0) >= 0.3]
        background = background_boxes(rng, [b for b, _ in parts], image.rgb.shape[:2],
                                      per_frame)
        frames.append((image.rgb, image.intrinsics.K, [b for b, _ in parts],
                       np.array([i for _, i in parts]), background))
    return frames


def answers(model, frames, which: str) -> tuple[np.ndarray, np.ndarray]:
    """(ids, margins) of the model on every part box (``which='parts'``) or background box."""
    ids, margins = [], []
    for rgb, K, parts, _, background in frames:
        boxes = parts if which == 'parts' else background
        if not boxes:
            continue
        scores = model.decision_function(model.describe(rgb, None, boxes, K=K))
        prediction = model.predict_scores(scores, reject_margin=0.0)
        ids.append(prediction.class_ids)
        margins.append(prediction.margins)
    return np.concatenate(ids), np.concatenate(margins)


def train(dataset: Path, out: Path, ids: list[int] | None) -> Path:
    out.parent.mkdir(parents=True, exist_ok=True)
    if not out.is_file():
        extra = [] if ids is None else ['--ids', *map(str, ids)]
        subprocess.run([sys.executable, '-m', 'tlessbot_ros.tools.cli', 'train', '--models',
                        str(dataset / 'models'), '--out', str(out), *extra], check=True,
                       stdout=subprocess.DEVNULL)
    return out


def main(argv: list[str] | None = None) -> int:
    from tlessbot_ros.core.recognise import LinearClassifier

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True)
    parser.add_argument('--out', type=Path, default=Path('reports/real_unknown'))
    parser.add_argument('--classifier', type=Path, help='default: train one (defaults)')
    parser.add_argument('--boxes-per-frame', type=int, default=20)
    parser.add_argument('--leave-one-out', action='store_true')
    args = parser.parse_args(argv)
    frames = real_boxes(args.dataset, args.boxes_per_frame)
    truth = np.concatenate([f[3] for f in frames])
    model = LinearClassifier.load(args.classifier or train(args.dataset,
                                                           args.out / 'all.npz', None))
    part_ids, part_margins = answers(model, frames, 'parts')
    back_ids, back_margins = answers(model, frames, 'background')
    held = {}
    if args.leave_one_out:
        every = sorted(set(truth.tolist()))
        for left in every:
            other = LinearClassifier.load(train(args.dataset, args.out / f'without_{left}.npz',
                                                [i for i in every if i != left]))
            only = [(rgb, K, [b for b, i in zip(parts, ids) if i == left], None, [])
                    for rgb, K, parts, ids, _ in frames]
            held[left] = answers(other, only, 'parts')[1] / max(other.margin_scale, 1e-9)
    scale = max(model.margin_scale, 1e-9)
    lines = [f'- {len(frames)} frames, {len(truth)} parts, {len(back_ids)} background boxes '
             f'({args.boxes_per_frame} per frame); margin_scale {model.margin_scale:.3f}', '',
             '| reject below × margin_scale | parts top-1 | parts called unknown | background '
             'named as a part | false positives per frame | left-out parts called unknown |',
             '|---|---|---|---|---|---|']
    curve = []
    for fraction in FRACTIONS:
        keep_parts = (part_ids != 0) & (part_margins >= fraction * scale)
        keep_back = (back_ids != 0) & (back_margins >= fraction * scale)
        top1 = float(np.mean((part_ids == truth) & keep_parts))
        fp = float(np.mean(keep_back))
        left = (np.mean(np.concatenate([m < fraction for m in held.values()]))
                if held else None)
        curve.append((fraction, top1, fp, left))
        lines.append(f'| {fraction:.1f} | {top1:.3f} | {1 - np.mean(keep_parts):.3f} | '
                     f'{fp:.3f} | {fp * args.boxes_per_frame:.1f} | '
                     + ('n/a' if left is None else f'{left:.3f}') + ' |')
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / 'unknown.md').write_text('\n'.join(lines) + '\n', encoding='utf-8')
    print('\n'.join(lines))
    _plot(curve, args.out / 'unknown.png')
    return 0


def _plot(curve, path: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fractions = [c[0] for c in curve]
    fig, ax = plt.subplots(figsize=(6, 4))
    ax.plot(fractions, [c[1] for c in curve], 'o-', label='parts top-1 (rejected = wrong)')
    ax.plot(fractions, [c[2] for c in curve], 's-', label='background boxes named a part')
    if curve[0][3] is not None:
        ax.plot(fractions, [c[3] for c in curve], '^-', label='left-out part called unknown')
    ax.set_xlabel('reject threshold × margin_scale')
    finish_plot(fig, [ax], path)


def finish_plot(fig, axes, path: Path, *, top: float = 1.0, legend_size: int = 8) -> None:
    """Y range 0..``top``, grid and legend on every axis, then the PNG at ``path``."""
    import matplotlib.pyplot as plt

    for ax in axes:
        ax.set_ylim(0, top)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=legend_size)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


if __name__ == '__main__':
    sys.exit(main())
