"""How each ground-truth part of an evaluated BOP set ended, by cause.

    python scripts/own_parts_why.py SCENES MODELS ESTIMATES_CSV [--flat-mm 6]

SCENES: a scenes folder of ``tlessbot simulate`` / ``bench own-parts`` (scored, like
``tlessbot evaluate``, in its first camera, ``test_side``); MODELS: its models folder with
models_info.json (symmetries); ESTIMATES_CSV: ``tlessbot evaluate``'s estimates.csv.

Per part: ok (within 5 cm / 5 deg modulo the listed symmetries), none (no pose of its class
within 5 cm: missed, merged or named as another part), far, or wrong with the gravity
direction in the part off by < 5 deg (a turn about the vertical), 5-20, 20-100 or > 100 deg
(upside down). Then the flat parts (thinnest side <= --flat-mm) lying on a face, standing on an
edge (thin axis within 20 deg of level) or tilted.
"""
from __future__ import annotations

import argparse
import csv
import json
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common.symmetry import symmetries_from_models_info


def _angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R_a.T @ R_b) - 1) / 2, -1, 1))))


def _estimates(path: Path) -> dict[tuple[int, int, int], list[np.ndarray]]:
    out: dict[tuple[int, int, int], list[np.ndarray]] = defaultdict(list)
    with path.open() as f:
        for row in csv.DictReader(f):
            T = np.eye(4)
            T[:3, :3] = np.array(row['R'].split(), float).reshape(3, 3)
            T[:3, 3] = np.array(row['t'].split(), float) / 1000
            out[(int(row['scene_id']), int(row['im_id']), int(row['obj_id']))].append(T)
    return out


def _outcome(candidates: list[np.ndarray], R_gt: np.ndarray, t_gt: np.ndarray,
             turns: list[np.ndarray], up_c: np.ndarray) -> str:
    if not candidates:
        return 'none'
    T = min(candidates, key=lambda T: float(np.linalg.norm(T[:3, 3] - t_gt)))
    if np.linalg.norm(T[:3, 3] - t_gt) > 0.05:
        return 'far'
    R_sym = min((R_gt @ S for S in turns), key=lambda R: _angle_deg(T[:3, :3], R))
    if _angle_deg(T[:3, :3], R_sym) < 5:
        return 'ok'
    tilt = np.degrees(np.arccos(np.clip((T[:3, :3].T @ up_c) @ (R_sym.T @ up_c), -1, 1)))
    return ('tilt<5' if tilt < 5 else 'tilt5-20' if tilt < 20 else
            'tilt20-100' if tilt < 100 else 'tilt>100')


def symmetry_turns(info: dict) -> dict[str, list[np.ndarray]]:
    """models_info.json's entries -> each part's symmetry rotations, (3, 3) each (a continuous
    axis in 1 deg steps)."""
    return {k: [S[:3, :3] for S in symmetries_from_models_info(v).transforms(
        step_rad=np.radians(1))] for k, v in info.items()}


def side_parts(scenes: Path) -> Iterator[tuple[int, int, int, dict, np.ndarray]]:
    """Every ground-truth part of the scored camera (``test_side``): (scene id, image id, index
    in the image, its scene_gt entry, the table's up direction (3,) in that camera)."""
    for scene in sorted((scenes / 'test_side').iterdir()):
        gt = json.loads((scene / 'scene_gt.json').read_text())
        cameras = json.loads((scene / 'scene_camera.json').read_text())
        for im, parts in gt.items():
            up_c = np.array(cameras[im]['cam_R_w2c']).reshape(3, 3) @ np.array([0, 0, 1.0])
            for k, part in enumerate(parts):
                yield int(scene.name), int(im), k, part, up_c


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('scenes', type=Path)
    ap.add_argument('models', type=Path)
    ap.add_argument('estimates', type=Path)
    ap.add_argument('--flat-mm', type=float, default=6.0)
    ap.add_argument('--list', choices=('lying', 'standing', 'tilted'),
                    help='also print each flat part of this attitude that is not ok')
    args = ap.parse_args()
    info = json.loads((args.models / 'models_info.json').read_text())
    estimates = _estimates(args.estimates)
    per_part: dict[int, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    flat: dict[str, list[int]] = defaultdict(lambda: [0, 0])
    flat_outcomes: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    turns = symmetry_turns(info)
    for scene, im, _, part, up_c in side_parts(args.scenes):
        key = str(part['obj_id'])
        R_gt = np.array(part['cam_R_m2c']).reshape(3, 3)
        t_gt = np.array(part['cam_t_m2c']) / 1000
        found = estimates.get((scene, im, part['obj_id']), [])
        outcome = _outcome(found, R_gt, t_gt, turns[key], up_c)
        per_part[part['obj_id']][outcome] += 1
        size = np.array([info[key][f'size_{a}'] for a in 'xyz'])
        if size.min() <= args.flat_mm:
            thin = R_gt @ np.eye(3)[int(np.argmin(size))]
            angle = np.degrees(np.arccos(min(1.0, abs(float(thin @ up_c)))))
            attitude = 'lying' if angle < 20 else 'standing' if angle > 70 else 'tilted'
            flat[attitude][0] += 1
            flat[attitude][1] += outcome == 'ok'
            flat_outcomes[attitude][outcome] += 1
            if attitude == args.list and outcome != 'ok':
                print(f'  scene={scene:06d} im={im} obj={key} {outcome}')
    total: dict[str, int] = defaultdict(int)
    for obj_id, counts in sorted(per_part.items()):
        print(f'obj {obj_id:3d}: ' + ', '.join(f'{k} {v}' for k, v in sorted(counts.items())))
        for k, v in counts.items():
            total[k] += v
    print('all: ' + ', '.join(f'{k} {v}' for k, v in sorted(total.items())))
    for attitude, (n, ok) in sorted(flat.items()):
        print(f'flat parts {attitude}: {ok} of {n} ({ok / n:.3f}); ' + ', '.join(
            f'{k} {v}' for k, v in sorted(flat_outcomes[attitude].items()) if k != 'ok'))


if __name__ == '__main__':
    main()
