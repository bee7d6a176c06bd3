"""Top-1 per part on held-out capture bags: the localiser's crop of every frame, classified.

The crops are those ``tlessbot train --captures`` trains on (tools/support/captures.py): every
frame of every camera of each labelled capture bag, the part cut out by the localiser. Several
model files can be compared on the same crops:

    tlessbot bench captures --classifier cad.npz captures.npz mixed.npz \\
        --captures held_out/obj_* --out reports/captures

Writes <out>/captures.md (top-1 per part and model) and <out>/captures.json.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--classifier', type=Path, nargs='+', required=True,
                        help='one or more model .npz files (from tlessbot train)')
    parser.add_argument('--captures', type=Path, nargs='+', required=True, metavar='BAG',
                        help='labelled capture bags (tlessbot capture) not used in training')
    parser.add_argument('--every', type=int, default=1, help='use every N-th frame (1)')
    parser.add_argument('--config', type=Path, help='the cell YAML of the bags (its rig)')
    parser.add_argument('--out', type=Path, default=Path('reports/captures'))


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from tlessbot_ros.core.recognise import load_classifier
    from tlessbot_ros.tools.support.captures import capture_crops

    models = {path.stem: load_classifier(path) for path in args.classifier}
    truth: list[int] = []
    predicted: dict[str, list[int]] = {name: [] for name in models}
    skipped: list = []
    for bag in args.captures:
        for crop in tqdm(capture_crops(bag, config=args.config, every=args.every,
                                       skipped=skipped), desc=bag.name, unit='crop'):
            truth.append(crop.obj_id)
            for name, model in models.items():
                depth = {} if crop.T_world_camera is None else {
                    'depth_m': crop.depth_m, 'K': crop.K, 'T_world_camera': crop.T_world_camera}
                features = model.describe(crop.rgb, [crop.mask], [crop.box], **depth)
                prediction = model.predict_scores(model.decision_function(features),
                                                  reject_margin=0.0)
                predicted[name].append(int(prediction.class_ids[0]))
    table = format_table(np.asarray(truth), {k: np.asarray(v) for k, v in predicted.items()})
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / 'captures.md').write_text(
        f'{len(truth)} crops of {len(args.captures)} capture bags ({len(skipped)} frame views '
        f'without a part found)\n\n{table}\n', encoding='utf-8')
    (args.out / 'captures.json').write_text(json.dumps({
        'bags': [str(b) for b in args.captures], 'crops': len(truth), 'skipped': len(skipped),
        'top1': {name: float(np.mean(np.asarray(p) == np.asarray(truth))) if truth else None
                 for name, p in predicted.items()}}, indent=1), encoding='utf-8')
    print(table)
    print(f'-> {args.out / "captures.md"}')
    return 0


def format_table(truth: np.ndarray, predicted: dict[str, np.ndarray]) -> str:
    """Markdown: one row per part (crops, top-1 of each model), then all parts."""
    names = list(predicted)
    lines = ['| part | crops | ' + ' | '.join(names) + ' |',
             '|---|---:|' + '---:|' * len(names)]
    for obj_id in sorted(set(truth.tolist())):
        rows = truth == obj_id
        lines.append(f'| obj_{obj_id:02d} | {int(rows.sum())} | ' + ' | '.join(
            f'{np.mean(predicted[n][rows] == obj_id):.2f}' for n in names) + ' |')
    lines.append(f'| **all** | {len(truth)} | ' + ' | '.join(
        f'**{np.mean(predicted[n] == truth):.2f}**' if len(truth) else '-' for n in names)
        + ' |')
    return '\n'.join(lines)
