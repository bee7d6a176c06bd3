"""Outcomes of scenes of scripts/other_renderer_scenes.py by what was drawn for them: each
part's outcome (scripts/own_parts_why.py's: ok, none, far, tilt...) by its material, and per
table kind the share of parts ok and the poses outside the side image (false ones that
`evaluate` cannot score: scripts/unseen_estimates.py). docs/bench/other-renderer.md.

    python scripts/other_renderer_why.py SCENES MODELS ESTIMATES_CSV
"""
from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from own_parts_why import _estimates, _outcome, symmetry_turns  # noqa: E402


def _table(title: str, rows: dict[str, dict[str, int]]) -> None:
    print(f'\n| {title} | parts | ok | none | far | wrong rotation |\n|---|---|---|---|---|---|')
    for key, counts in sorted(rows.items()):
        n = sum(counts.values())
        wrong = sum(v for k, v in counts.items() if k.startswith('tilt'))
        print(f"| {key} | {n} | {counts['ok'] / n:.2f} | {counts['none']} | {counts['far']} | "
              f'{wrong} |')


def main(scenes: Path, models: Path, estimates_csv: Path) -> None:
    info = json.loads((models / 'models_info.json').read_text())
    drawn = json.loads((scenes / 'other_renderer.json').read_text())
    estimates = _estimates(estimates_csv)
    turns = symmetry_turns(info)
    folder = scenes / 'test_side' / '000000'
    gt = json.loads((folder / 'scene_gt.json').read_text())
    cameras = json.loads((folder / 'scene_camera.json').read_text())
    by_material: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    by_table: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    unseen: dict[str, list[int]] = defaultdict(lambda: [0, 0])   # frames, poses outside
    for im, parts in gt.items():
        camera = cameras[im]
        K = np.array(camera['cam_K']).reshape(3, 3)
        up_c = np.array(camera['cam_R_w2c']).reshape(3, 3) @ np.array([0, 0, 1.0])
        table = drawn[im]['table']
        for part, material in zip(parts, drawn[im]['materials']):
            found = estimates.get((0, int(im), part['obj_id']), [])
            outcome = _outcome(found, np.array(part['cam_R_m2c']).reshape(3, 3),
                               np.array(part['cam_t_m2c']) / 1000, turns[str(part['obj_id'])],
                               up_c)
            by_material[material][outcome] += 1
            by_table[table][outcome] += 1
        unseen[table][0] += 1
        for (_, image, _), poses in estimates.items():
            if image == int(im):
                for T in poses:
                    u, v, w = K @ T[:3, 3]
                    unseen[table][1] += not (w > 0 and 0 <= u / w < 640 and 0 <= v / w < 480)
    _table('material', by_material)
    _table('table', by_table)
    print('\nposes outside the side image a frame: ' + ', '.join(
        f'{k} {n / f:.2f} ({f} frames)' for k, (f, n) in sorted(unseen.items())))


if __name__ == '__main__':
    main(*map(Path, sys.argv[1:4]))
