"""Parts that are not T-LESS next to T-LESS: end-to-end scores on one simulator run per set.

    tlessbot bench own-parts --set generated=my_parts --set sygrid=sygrid_parts \\
        --reference ../shared/data/tless_models_cad_stl --frames 30 --out own_parts_bench

Each --set NAME=PARTS (a parts folder of ``tlessbot parts build``) is simulated with the same
settings and seed as the reference (T-LESS CAD models, eight of them, scored with the packaged
classifier and templates), run through the pipeline (``tlessbot evaluate``) and scored: 5 cm /
5°, top-1, detection (IoU > 0.7) and false positives per frame, for all parts and for the flat
ones (thinnest side <= --flat-mm), then per set a table per part with its misses by cause
and the false positives by cause (``tlessbot evaluate``'s breakdown). Writes report.md and
report.json to --out. ``--depth-model smoothed`` simulates the depth a real stereo camera
gives (smoothed, correlated; ``tlessbot simulate --depth-model``).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from tlessbot_ros.sim.noise import DEPTH_KINDS

TLESS_IDS = (2, 5, 8, 11, 14, 19, 25, 30)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--set', action='append', default=[], metavar='NAME=PARTS',
                        help='a parts folder to score (repeatable)')
    parser.add_argument('--reference', type=Path, help='T-LESS CAD models folder (obj_NN.stl)')
    parser.add_argument('--reference-ids', type=int, nargs='+', default=list(TLESS_IDS))
    parser.add_argument('--frames', type=int, default=30)
    parser.add_argument('--seed', type=int, default=4100)
    parser.add_argument('--flat-mm', type=float, default=6.0,
                        help='a part whose thinnest side is at most this is flat (6 mm)')
    parser.add_argument('--depth-model', choices=DEPTH_KINDS, default='per_pixel',
                        help="the simulated depth (simulate's --depth-model): smoothed is "
                             'stereo-like, as a real RealSense gives it')
    parser.add_argument('--out', type=Path, default=Path('own_parts_bench'))


def _score(name: str, models: Path, out: Path, args, *, classifier=None, templates=None,
           ids=None) -> dict:
    from tlessbot_ros.tools.support.parts_build import run_tool

    data = out / name / 'scenes'
    ids_arg = ['--ids', *map(str, ids)] if ids else []
    run_tool('simulate', '--models', str(models), '--out', str(data), '--frames',
             str(args.frames), '--seed', str(args.seed), '--parts-min', '3', '--parts-max', '8',
             '--depth-model', args.depth_model, *ids_arg)
    more = ['--classifier', str(classifier), '--templates', str(templates)] if classifier else []
    started = time.perf_counter()
    run_tool('evaluate', '--dataset', str(data), '--models', str(models), '--out',
             str(out / name / 'eval'), *more)
    report = json.loads((out / name / 'eval' / 'report.json').read_text())
    info = json.loads((models / 'models_info.json').read_text()) \
        if (models / 'models_info.json').is_file() else {}
    flat = [k for k, v in info.items() if min(v['size_x'], v['size_y'], v['size_z'])
            <= args.flat_mm]
    per = report['per_object']
    n_flat = sum(per[k]['objects_gt'] for k in flat if k in per)
    flat_pose = (sum(per[k]['recall_5cm5deg'] * per[k]['objects_gt'] for k in flat if k in per)
                 / n_flat) if n_flat else None
    return {'name': name, 'frames': report['frames'], 'parts_gt': report['objects_gt'],
            'pose': report['pose']['recall_5cm5deg'], 'top1': report['recognition']['top1'],
            'detected': report['detection']['iou07_rate'],
            'false_pos': report['detection']['false_pos_per_frame'],
            'flat_parts_gt': n_flat, 'flat_pose': flat_pose,
            'per_object': {k: v.get('recall_5cm5deg') for k, v in per.items()},
            'per_part': {k: {key: v.get(key) for key in ('objects_gt', 'iou07_rate', 'top1',
                                                          'recall_5cm5deg')}
                         for k, v in per.items()},
            'breakdown': report['detection'].get('breakdown'),
            'names': report.get('names', {}),   # as evaluate names them
            'eval_s': round(time.perf_counter() - started, 1)}


def _table(rows: list[dict]) -> str:
    def cell(value):
        return '-' if value is None else f'{value:.3f}'

    lines = ['| parts | frames | parts scored | 5 cm / 5° | top-1 | detection IoU > 0.7 | '
             'false positives / frame | flat parts (n) 5 cm / 5° |', '|---' * 8 + '|']
    for r in rows:
        lines.append(f"| {r['name']} | {r['frames']} | {r['parts_gt']} | {cell(r['pose'])} | "
                     f"{cell(r['top1'])} | {cell(r['detected'])} | {cell(r['false_pos'])} | "
                     f"{cell(r['flat_pose'])} ({r['flat_parts_gt']}) |")
    return '\n'.join(lines)


def _losses(row: dict) -> list[str]:
    """One set's per-part table (with its misses by cause) and false positives by cause."""
    from tlessbot_ros.tools.support.eval_breakdown import FP_CAUSES, MISS_CAUSES

    def cell(value):
        return '-' if value is None else f'{value:.2f}'

    loss = row.get('breakdown')
    names = row.get('names', {})
    lines = ['', f"### {row['name']}", '', '| part | n | detected | top-1 | 5 cm / 5° | missed: '
             + ', '.join(MISS_CAUSES) + ' |', '|---' * 6 + '|']
    for key, v in sorted(row['per_part'].items(), key=lambda kv: int(kv[0])):
        missed = (loss or {}).get('missed_by_obj', {}).get(key, {})
        lines.append(f"| {names.get(key, 'obj_' + key)} | {v['objects_gt']} | "
                     f"{cell(v['iou07_rate'])} | {cell(v['top1'])} | "
                     f"{cell(v['recall_5cm5deg'])} | "
                     + ', '.join(str(missed.get(c, 0)) for c in MISS_CAUSES) + ' |')
    if loss:
        lines += ['', 'False positives by cause (with a pose): ' + ', '.join(
            f"{c} {loss['false_pos'][c]} ({loss['false_pos_posed'][c]})" for c in FP_CAUSES
            if loss['false_pos'][c]) or 'none', '', 'Named as another part: ' + (', '.join(
                f"{' -> '.join(names.get(i, i) for i in k.split(' -> '))} ({n})"
                for k, n in loss['confusions'].items()) or 'none') + '.']
    return lines


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_TEMPLATES
    from tlessbot_ros.errors import TlessbotError
    from tlessbot_ros.io.parts import open_parts_folder

    sets = []
    for item in args.set:
        name, _, path = item.partition('=')
        if not name or not path:
            raise TlessbotError(f'--set wants NAME=PARTS_FOLDER, got {item!r}')
        sets.append((name, open_parts_folder(path)))
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []
    if args.reference is not None:
        rows.append(_score('T-LESS_packaged', args.reference, args.out, args,
                           classifier=DEFAULT_CLASSIFIER, templates=DEFAULT_TEMPLATES,
                           ids=args.reference_ids))
    for name, folder in sets:
        rows.append(_score(name, folder.models, args.out, args, classifier=folder.classifier,
                           templates=folder.templates))
    heading = (f'Simulated depth: {args.depth_model}, seed {args.seed}, {args.frames} frames '
               'a set.')
    losses = sum((_losses(r) for r in rows), [])
    table = '\n'.join([heading, '', _table(rows), '', '## Losses per set', *losses])
    (args.out / 'report.json').write_text(json.dumps(rows, indent=1) + '\n')
    (args.out / 'report.md').write_text(table + '\n')
    print(table)
    return 0
