"""Each flat part lying on a face that smoothed depth loses, beside the same part on per-pixel
depth (the same scenes, the same ground truth), by cause.

    python scripts/flat_lying_trace.py PERPIX_OUT SMOOTH_OUT [--cells 4100:g 4242:h7 ...]
        [--bench /work/bench] [--smooth /work/bench-smooth] [--flat-mm 6] [--list]

PERPIX_OUT / SMOOTH_OUT: ``own_parts_bench.sh eval`` outputs (OUT/SEED/SET/estimates.csv).
A part's outcome is own_parts_why.py's (ok, far, tilt<5 = yaw off, tilt5-20 / tilt20-100 =
tilted, tilt>100 = turned over) with its "none" split by own_parts_none.py's cause from the
estimates alone (missed, named = another class, merged, other).
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from own_parts_none import none_parts  # noqa: E402
from own_parts_why import _estimates, _outcome, side_parts, symmetry_turns  # noqa: E402

FLAT_CELLS = ('4100:g', '4242:g', '4343:g', '4100:h7', '4242:h7', '4100:h8', '4242:h8')
NAMES = {'tilt<5': 'yaw', 'tilt5-20': 'tilt', 'tilt20-100': 'tilt', 'tilt>100': 'over',
         'far': 'far', 'ok': 'ok'}


def lying_outcomes(scenes: Path, models: Path, estimates: Path, flat_mm: float
                   ) -> dict[tuple[int, int, int], tuple[int, str]]:
    """(scene, im, gt index) -> (obj, cause) of every flat part lying on a face."""
    info = json.loads((models / 'models_info.json').read_text())
    turns = symmetry_turns(info)
    est = _estimates(estimates)
    nones = {(r['scene'], r['im'], r['gt']): r['cause']
             for r in none_parts(scenes, estimates, 0.015)}
    out = {}
    for scene, im, k, part, up_c in side_parts(scenes):
        key = str(part['obj_id'])
        size = np.array([info[key][f'size_{a}'] for a in 'xyz'])
        if size.min() > flat_mm:
            continue
        R_gt = np.array(part['cam_R_m2c']).reshape(3, 3)
        thin = R_gt @ np.eye(3)[int(np.argmin(size))]
        if np.degrees(np.arccos(min(1.0, abs(float(thin @ up_c))))) >= 20:
            continue
        found = est.get((scene, im, part['obj_id']), [])
        outcome = _outcome(found, R_gt, np.array(part['cam_t_m2c']) / 1000, turns[key], up_c)
        where = (scene, im, k)
        cause = nones[where] if outcome == 'none' else NAMES[outcome]
        out[where] = (part['obj_id'], cause)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('perpix', type=Path)
    ap.add_argument('smooth', type=Path)
    ap.add_argument('--cells', nargs='+', default=list(FLAT_CELLS))
    ap.add_argument('--bench', type=Path, default=Path('/work/bench'))
    ap.add_argument('--smooth-scenes', type=Path, default=Path('/work/bench-smooth'))
    ap.add_argument('--flat-mm', type=float, default=6.0)
    ap.add_argument('--list', action='store_true', help='print each part lost on smoothed')
    args = ap.parse_args()
    causes: Counter = Counter()
    pairs: Counter = Counter()
    by_obj: dict[str, Counter] = defaultdict(Counter)
    total = ok = 0
    for cell in args.cells:
        seed, kind = cell.split(':')
        models = args.bench / 'parts' / kind / 'models'
        smooth = lying_outcomes(args.smooth_scenes / f'{seed}-{kind}', models,
                                args.smooth / seed / kind / 'estimates.csv', args.flat_mm)
        perpix = lying_outcomes(args.bench / 'scenes' / f'{seed}-{kind}', models,
                                args.perpix / seed / kind / 'estimates.csv', args.flat_mm)
        cell_causes = Counter(c for _, c in smooth.values() if c != 'ok')
        total += len(smooth)
        ok += sum(c == 'ok' for _, c in smooth.values())
        kept = Counter(c for w, (_, c) in smooth.items() if c != 'ok' and perpix[w][1] == 'ok')
        print(f'{cell}: {sum(c == "ok" for _, c in smooth.values())} of {len(smooth)} ok; '
              + ', '.join(f'{k} {v} ({kept[k]} ok per-pixel)'
                          for k, v in sorted(cell_causes.items())))
        for where, (obj, cause) in sorted(smooth.items()):
            if cause == 'ok':
                continue
            causes[cause] += 1
            pairs[(cause, perpix[where][1])] += 1
            by_obj[f'{kind}:{obj}'][cause] += 1
            if args.list:
                print(f'  {cell} scene={where[0]} im={where[1]} gt={where[2]} obj={obj} '
                      f'smoothed={cause} perpix={perpix[where][1]}')
    print(f'all: {ok} of {total} ok; ' + ', '.join(f'{k} {v}' for k, v in sorted(causes.items())))
    print('smoothed cause <- per-pixel outcome of the same part:')
    for (s, p), n in sorted(pairs.items()):
        print(f'  {s:8s} {p:8s} {n}')
    print('by part: ' + '; '.join(f'{k} ' + ', '.join(f'{c} {n}' for c, n in sorted(v.items()))
                                  for k, v in sorted(by_obj.items())))


if __name__ == '__main__':
    main()
