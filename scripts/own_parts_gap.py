"""Each cell's lost parts by cause, and how many parts close its gap to T-LESS (issue 41).

    python scripts/own_parts_gap.py BENCH OUT SEED:SET... [--scenes DIR] [--margin 0.05] [--list]

BENCH: the own-parts bench (parts/SET with models and manifest.json); OUT: an ``eval`` output
(OUT/SEED/SET/estimates.csv and report.json, OUT/SEED/T/report.json for the target);
``--scenes`` defaults to BENCH/scenes. Every part not within 5 cm / 5 deg gets one cause:

* ``twin``: named as its listed look-alike at its place (own_parts_none.py ``named``);
* ``named``: named as another, unlisted part; ``merged``, ``missed``, ``other``: the rest of
  own_parts_none.py's causes (``other`` holds own_parts_why.py's ``far``);
* ``upside``: its class, gravity in the part off by > 100 deg; ``tilt``: 5-100 deg;
  ``yaw``: < 5 deg (a turn about the vertical).

and an attitude: ``standing`` (a flat part on an edge, as own_parts_why.py), ``lying``,
``tilted`` or ``bulky`` (thinnest side over --flat-mm). Per cell: the parts needed to come
within ``--margin`` of the same seed's T-LESS recall, and for each cause (and for standing
parts) whether fixing all of them would close the gap.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from own_parts_none import none_parts  # noqa: E402
from own_parts_why import _estimates, _outcome, symmetry_turns  # noqa: E402

CAUSES = ('twin', 'named', 'merged', 'missed', 'other', 'upside', 'tilt', 'yaw')


def _lookalikes(manifest: Path) -> set[tuple[int, int]]:
    parts = json.loads(manifest.read_text())['parts']
    ids = {p['name']: p['id'] for p in parts}
    return {(p['id'], ids[q]) for p in parts for q in p['lookalikes'] if q in ids}


def _attitude(size: np.ndarray, R_gt: np.ndarray, up_c: np.ndarray, flat_mm: float) -> str:
    if size.min() > flat_mm:
        return 'bulky'
    thin = R_gt @ np.eye(3)[int(np.argmin(size))]
    angle = np.degrees(np.arccos(min(1.0, abs(float(thin @ up_c)))))
    return 'lying' if angle < 20 else 'standing' if angle > 70 else 'tilted'


def lost_parts(scenes: Path, models: Path, estimates: Path, manifest: Path,
               flat_mm: float) -> tuple[int, int, list[dict]]:
    """(parts, ok, one row per lost part: im, obj, cause, attitude)."""
    info = json.loads((models / 'models_info.json').read_text())
    turns = symmetry_turns(info)
    twins = _lookalikes(manifest)
    none_cause = {}
    for r in none_parts(scenes, estimates, 0.015):
        cause = r['cause']
        if cause == 'named':
            a, b = (int(x) for x in r['detail'].split()[0].split('->'))
            cause = 'twin' if (a, b) in twins else 'named'
        none_cause[(r['scene'], r['im'], r['gt'])] = cause
    est = _estimates(estimates)
    total = ok = 0
    rows = []
    for scene in sorted((scenes / 'test_side').iterdir()):
        gt = json.loads((scene / 'scene_gt.json').read_text())
        cameras = json.loads((scene / 'scene_camera.json').read_text())
        visible = json.loads((scene / 'scene_gt_info.json').read_text())
        for im, parts in gt.items():
            up_c = np.array(cameras[im]['cam_R_w2c']).reshape(3, 3) @ np.array([0, 0, 1.0])
            for k, part in enumerate(parts):
                if visible[im][k].get('visib_fract', 0.0) < 0.3:
                    continue   # as `tlessbot evaluate` scores
                total += 1
                key = str(part['obj_id'])
                R_gt = np.array(part['cam_R_m2c']).reshape(3, 3)
                found = est.get((int(scene.name), int(im), part['obj_id']), [])
                outcome = _outcome(found, R_gt, np.array(part['cam_t_m2c']) / 1000,
                                   turns[key], up_c)
                if outcome == 'ok':
                    ok += 1
                    continue
                cause = {'tilt>100': 'upside', 'tilt<5': 'yaw', 'tilt5-20': 'tilt',
                         'tilt20-100': 'tilt'}.get(outcome) or none_cause.get(
                             (int(scene.name), int(im), k), 'other')
                size = np.array([info[key][f'size_{a}'] for a in 'xyz'])
                rows.append({'im': int(im), 'gt': k, 'obj': part['obj_id'], 'cause': cause,
                             'attitude': _attitude(size, R_gt, up_c, flat_mm)})
    return total, ok, rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('bench', type=Path)
    ap.add_argument('out', type=Path)
    ap.add_argument('cells', nargs='+', help='SEED:SET')
    ap.add_argument('--scenes', type=Path)
    ap.add_argument('--margin', type=float, default=0.05)
    ap.add_argument('--flat-mm', type=float, default=6.0)
    ap.add_argument('--list', action='store_true', help='also print each lost part')
    args = ap.parse_args()
    scenes_root = args.scenes or args.bench / 'scenes'
    print('| cell | recall | T-LESS | parts needed | ' + ' | '.join(CAUSES) +
          ' | of which standing | closes it |')
    print('|' + '---|' * (len(CAUSES) + 6))
    for cell in args.cells:
        seed, k = cell.split(':')
        parts_dir = args.bench / 'parts' / k
        total, ok, rows = lost_parts(scenes_root / f'{seed}-{k}', parts_dir / 'models',
                                     args.out / seed / k / 'estimates.csv',
                                     parts_dir / 'manifest.json', args.flat_mm)
        target = json.loads((args.out / seed / 'T' / 'report.json').read_text())[
            'pose']['recall_5cm5deg'] - args.margin
        needed = max(0, math.ceil(target * total - 1e-9) - ok)
        causes = Counter(r['cause'] for r in rows)
        standing = Counter(r['cause'] for r in rows if r['attitude'] == 'standing')
        closes = [c for c in CAUSES if causes[c] >= needed] + \
            (['standing'] if sum(standing.values()) >= needed else [])
        standing_text = ', '.join(f'{c} {n}' for c, n in sorted(standing.items()))
        print(f'| {seed} {k} | {ok / total:.3f} ({ok}/{total}) | {target + args.margin:.3f} '
              f'| {needed} | ' + ' | '.join(str(causes[c]) for c in CAUSES) +
              f' | {sum(standing.values())} ({standing_text}) | {", ".join(closes) or "-"} |')
        if args.list:
            for r in rows:
                print(f'  {seed} {k} ' + ' '.join(f'{a}={b}' for a, b in r.items()))


if __name__ == '__main__':
    main()
