"""Blocks (parts that are no flat part, no symmetry) that end turned: is the turn one the pose
stage's half-turn check compares, and do the two cameras show it at the true pose?

    python scripts/block_turns_why.py SCENES MODELS TEMPLATES ESTIMATES_CSV --obj 1

SCENES: a scenes folder of ``tlessbot bench own-parts`` (``test_side`` and ``test_top``,
scored like ``tlessbot evaluate`` in ``test_side``); MODELS: its models folder
(models_info.json); TEMPLATES: the templates the evaluation used (their meshes and listings);
ESTIMATES_CSV: ``tlessbot evaluate``'s estimates.csv.

Per part of ``--obj``: the angle of its model z axis (a generated block's drilled holes) to
the vertical; how it ended (ok within 5 cm / 5 deg, none, far, or wrong with the turn from the
truth to the estimate: its angle and axis in the model frame); for a wrong one the listed half
turn nearest that turn (:func:`~tlessbot_ros.core.pose.half_turns.self_half_turns`, ``box``
where it maps the hull onto itself: :func:`~tlessbot_ros.core.pose.half_turns.box_turns`)
and its residual angle; for every part the pixels each camera shows change when the part at
its true pose is turned by each box turn
(:func:`~tlessbot_ros.core.pose.observability.changed_pixels`: depth beyond 3 sigma of the
simulator's D415 model, or a rendered edge moved by more than a pixel), top / side.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from own_parts_why import _angle_deg, _estimates  # noqa: E402
from standing_why import _w2c  # noqa: E402


def _axis(R: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eig(R)
    a = np.real(V[:, int(np.argmin(np.abs(w - 1)))])
    return a * np.sign(a[np.argmax(np.abs(a))])


def _views(scenes: Path, scene: str, im: str) -> list:
    from tlessbot_ros.core.common import CameraIntrinsics
    from tlessbot_ros.core.pose import ViewOfTable

    out = []
    for name in ('top', 'side'):
        cam = json.loads((scenes / f'test_{name}' / scene / 'scene_camera.json').read_text())[im]
        meta = json.loads((scenes / f'camera_{name}.json').read_text())
        K = np.array(cam['cam_K'], float).reshape(3, 3)
        out.append(ViewOfTable(CameraIntrinsics(int(meta['width']), int(meta['height']), K),
                               np.linalg.inv(_w2c(cam))))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('scenes', type=Path)
    ap.add_argument('models', type=Path)
    ap.add_argument('templates', type=Path)
    ap.add_argument('estimates', type=Path)
    ap.add_argument('--obj', type=int, action='append', required=True)
    args = ap.parse_args()

    from tlessbot_ros.core.common import raycasting_scene
    from tlessbot_ros.core.pose import ObservabilityParams, TemplateDatabase, TurnParams
    from tlessbot_ros.core.pose.half_turns import box_turns, self_half_turns
    from tlessbot_ros.core.pose.observability import changed_pixels

    database = TemplateDatabase.load(args.templates)
    estimates = _estimates(args.estimates)
    params, seen = TurnParams(), ObservabilityParams()
    for obj_id in args.obj:
        obj = database[obj_id]
        turns = self_half_turns(obj, min_share=params.half_min_share,
                                exact_ratio=params.exact_ratio,
                                exact_quantile=params.exact_quantile)
        box = box_turns(obj, turns, params)
        mesh = raycasting_scene(np.asarray(obj.mesh_vertices, np.float64), obj.mesh_faces)
        points = obj.model_points.astype(np.float64)
        for scene in sorted((args.scenes / 'test_side').iterdir()):
            gt = json.loads((scene / 'scene_gt.json').read_text())
            cameras = json.loads((scene / 'scene_camera.json').read_text())
            for im, parts in gt.items():
                for part in (p for p in parts if p['obj_id'] == obj_id):
                    T_c = np.eye(4)
                    T_c[:3, :3] = np.array(part['cam_R_m2c']).reshape(3, 3)
                    T_c[:3, 3] = np.array(part['cam_t_m2c']) / 1000
                    T_world = np.linalg.inv(_w2c(cameras[im])) @ T_c
                    found = estimates.get((int(scene.name), int(im), obj_id), [])
                    outcome, extra = 'none', ''
                    if found:
                        T = min(found, key=lambda T: float(np.linalg.norm(T[:3, 3] - T_c[:3, 3])))
                        D = T_c[:3, :3].T @ T[:3, :3]
                        outcome = ('far' if np.linalg.norm(T[:3, 3] - T_c[:3, 3]) > 0.05 else
                                   'ok' if _angle_deg(np.eye(3), D) < 5 else
                                   f'{_angle_deg(np.eye(3), D):5.1f} deg about '
                                   f'{np.round(_axis(D), 2)}')
                        if outcome not in ('ok', 'far') and len(turns):
                            k = int(np.argmin([_angle_deg(S[:3, :3], D) for S in turns]))
                            extra = (f'; nearest listed half turn {"box" if box[k] else "refit"}'
                                     f' about {np.round(_axis(turns[k][:3, :3]), 2)}, '
                                     f'{_angle_deg(turns[k][:3, :3], D):.1f} deg off')
                    views = _views(args.scenes, scene.name, im)
                    px = ['/'.join(str(changed_pixels(mesh, points, T_world, T_world @ S, v,
                                                      seen)[2]) for v in views)
                          for S in turns[box]]
                    tilt = np.degrees(np.arccos(abs(T_world[2, 2])))
                    print(f'obj {obj_id} scene {int(scene.name)} im {int(im):3d} (model z '
                          f'{tilt:3.0f} deg off the vertical): {outcome}{extra}; px the box '
                          f'turns change (top/side) {", ".join(px)}')


if __name__ == '__main__':
    main()
