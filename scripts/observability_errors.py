"""Whether the cameras could see each pose error of an evaluated BOP set: pixels that tell the
estimate's rotation from the truth.

    python scripts/observability_errors.py SCENES MODELS ESTIMATES_CSV --ids 2,3

SCENES: a scenes folder of ``tlessbot simulate`` / ``bench own-parts`` (``test_side`` scored,
``test_top`` the second camera); MODELS: its models folder with models_info.json;
ESTIMATES_CSV: ``tlessbot evaluate``'s estimates.csv. For each ground-truth part of the
``--ids`` classes with an estimate within 5 cm: its rotation error (modulo the listed
symmetries), the axis of that error in the model frame, and the pixels of both cameras whose
depth (3 sigma of the noise) or colour edge (over a pixel) changes between the part at the
truth and the part turned by the estimate's rotation about its centre
(:func:`tlessbot_ros.core.pose.observability.changed_pixels`, noise-free renders, the table
behind). Prints one line per part, then the median per class and outcome.
"""
from __future__ import annotations

import argparse
import csv
import json
from collections import defaultdict
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    raycasting_scene,
    rotation_angle_deg,
    sample_surface,
    symmetries_from_models_info,
)
from tlessbot_ros.core.pose import ObservabilityParams, ViewOfTable, changed_pixels
from tlessbot_ros.io.models import load_models


def _pose(R, t_mm) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, float).reshape(3, 3)
    T[:3, 3] = np.asarray(t_mm, float) / 1000.0
    return T


def _view(entry: dict) -> ViewOfTable:
    K = np.array(entry['cam_K'], float).reshape(3, 3)
    return ViewOfTable(CameraIntrinsics(width=640, height=480, K=K),
                       np.linalg.inv(_pose(entry['cam_R_w2c'], entry['cam_t_w2c'])))


def _estimates(path: Path) -> dict:
    found = defaultdict(list)
    with open(path, newline='') as f:
        for row in csv.DictReader(f):
            found[(int(row['scene_id']), int(row['im_id']), int(row['obj_id']))].append(
                _pose(row['R'].split(), row['t'].split()))
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('scenes', type=Path)
    parser.add_argument('models', type=Path)
    parser.add_argument('estimates', type=Path)
    parser.add_argument('--ids', default='2,3', help='classes, comma-separated')
    args = parser.parse_args()
    ids = [int(i) for i in args.ids.split(',')]
    info = json.loads((args.models / 'models_info.json').read_text())
    models = load_models(args.models)
    params = ObservabilityParams()
    parts = {}
    for oid in ids:
        m = models[oid]
        parts[oid] = (raycasting_scene(m.vertices, m.faces),
                      sample_surface(m.vertices, m.faces, 3000)[0],
                      symmetries_from_models_info(info[str(oid)]).transforms(
                          step_rad=np.radians(1.0)))
    estimates = _estimates(args.estimates)
    by_outcome = defaultdict(list)
    for side_dir in sorted((args.scenes / 'test_side').iterdir()):
        top_dir = args.scenes / 'test_top' / side_dir.name
        truth = json.loads((side_dir / 'scene_gt.json').read_text())
        cams = [json.loads((d / 'scene_camera.json').read_text()) for d in (side_dir, top_dir)]
        for im, objs in truth.items():
            side, top = _view(cams[0][im]), _view(cams[1][im])
            for o in objs:
                if o['obj_id'] not in ids:
                    continue
                scene, points, symmetries = parts[o['obj_id']]
                Tg = _pose(o['cam_R_m2c'], o['cam_t_m2c'])
                found = estimates.get((int(side_dir.name), int(im), o['obj_id']), [])
                T = min(found, key=lambda T: np.linalg.norm(T[:3, 3] - Tg[:3, 3]), default=None)
                if T is None or np.linalg.norm(T[:3, 3] - Tg[:3, 3]) > 0.05:
                    continue
                Tg = min((Tg @ S for S in symmetries),
                         key=lambda X: rotation_angle_deg(T[:3, :3], X[:3, :3]))
                error = rotation_angle_deg(T[:3, :3], Tg[:3, :3])
                values, vectors = np.linalg.eig(Tg[:3, :3].T @ T[:3, :3])
                axis = np.abs(np.real(vectors[:, int(np.argmin(np.abs(values - 1.0)))]))
                centre = points.mean(axis=0)
                Te = Tg.copy()
                Te[:3, :3] = T[:3, :3]
                Te[:3, 3] = Tg[:3, 3] + Tg[:3, :3] @ centre - T[:3, :3] @ centre
                W = side.T_world_camera
                px = np.sum([changed_pixels(scene, points, W @ Tg, W @ Te, view, params)
                             for view in (side, top)], axis=0)
                outcome = 'ok' if error < 5.0 else 'wrong'
                by_outcome[(o['obj_id'], outcome)].append(px[2])
                print(f"obj {o['obj_id']} {outcome:5s} {error:6.1f} deg  axis "
                      f"{np.round(axis, 2)}  px depth {px[0]} edges {px[1]} either {px[2]}")
    for (oid, outcome), px in sorted(by_outcome.items()):
        print(f'obj {oid} {outcome}: {len(px)} parts, pixels changed median {np.median(px):.0f}'
              f' (range {min(px)}-{max(px)})')


if __name__ == '__main__':
    main()
