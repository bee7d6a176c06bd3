"""Flat parts standing on an edge: how each one ended, what the cameras see of its face, and
whether anything but its holes tells its faces apart.

    python scripts/standing_why.py SCENES MODELS ESTIMATES_CSV [--flat-mm 6]
    python scripts/standing_why.py --parts MODELS [--flat-mm 6]

SCENES: a scenes folder of ``tlessbot simulate`` / ``bench own-parts`` (``test_side`` and
``test_top``, scored like ``tlessbot evaluate`` in ``test_side``); MODELS: its models folder
(models_info.json, obj_NN.ply); ESTIMATES_CSV: ``tlessbot evaluate``'s estimates.csv.

Per standing flat part (thin axis within 20 deg of level): the outcome (ok within 5 cm / 5 deg
modulo the listed symmetries, none, far or wrong), the angle between its face's normal and each
camera's ray to it (a 5 mm hole through 4 mm of plate is blind beyond ~52 deg), and for a wrong
pose the turn that separates it from the truth: its angle, whether its axis is the part's thin
axis (the part stands on its opposite edge, same face to the camera), vertical (the face turned
away, same edge down) or level in the part's plane (both).

With ``--parts``: per flat part, the share of its outline (holes filled, seen along the thin
axis) that each half turn of :func:`~tlessbot_ros.core.pose.flat_turns.outline_half_turns`
changes (0: only the holes tell the turned part from the part), and the share of quasi-static
drops (:func:`~tlessbot_ros.core.common.resting.resting_poses`, the simulator's model) that end
standing, with the tilt that topples those poses onto a face.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from own_parts_why import _angle_deg, _estimates  # noqa: E402

from tlessbot_ros.core.common.symmetry import symmetries_from_models_info  # noqa: E402


def _w2c(camera: dict) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = np.array(camera['cam_R_w2c']).reshape(3, 3)
    T[:3, 3] = np.array(camera['cam_t_w2c']) / 1000
    return T


def _turn(R_gt: np.ndarray, R_est: np.ndarray, thin_o: np.ndarray, up_c: np.ndarray) -> str:
    """The turn from the truth to the estimate: angle and kind of axis."""
    D = R_gt.T @ R_est
    w, v = np.linalg.eig(D)
    axis = np.real(v[:, int(np.argmin(np.abs(w - 1)))])
    up_o = R_gt.T @ up_c
    kind = ('thin axis' if abs(axis @ thin_o) > 0.9 else 'vertical' if abs(axis @ up_o) > 0.9
            else 'level, in plane' if abs(axis @ thin_o) < 0.3 and abs(axis @ up_o) < 0.3
            else 'oblique')
    return f'{_angle_deg(np.eye(3), D):5.1f} deg about the {kind}'


def standing(scenes: Path, models: Path, estimates_csv: Path, flat_mm: float) -> None:
    info = json.loads((models / 'models_info.json').read_text())
    estimates = _estimates(estimates_csv)
    counts = {'ok': 0, 'all': 0}
    for scene in sorted((scenes / 'test_side').iterdir()):
        gt = json.loads((scene / 'scene_gt.json').read_text())
        side = json.loads((scene / 'scene_camera.json').read_text())
        top = json.loads((scenes / 'test_top' / scene.name / 'scene_camera.json').read_text())
        for im, parts in gt.items():
            T_side, T_top = _w2c(side[im]), _w2c(top[im])
            up_c = T_side[:3, :3] @ np.array([0, 0, 1.0])
            for part in parts:
                entry = info[str(part['obj_id'])]
                size = np.array([entry[f'size_{a}'] for a in 'xyz'])
                if size.min() > flat_mm:
                    continue
                R_gt = np.array(part['cam_R_m2c']).reshape(3, 3)
                t_gt = np.array(part['cam_t_m2c']) / 1000
                thin_o = np.eye(3)[int(np.argmin(size))]
                if abs(float((R_gt @ thin_o) @ up_c)) > np.cos(np.radians(70)):
                    continue   # lying or tilted
                T_world = np.linalg.inv(T_side)
                normal_w = T_world[:3, :3] @ R_gt @ thin_o
                centre_w = T_world[:3, :3] @ t_gt + T_world[:3, 3]
                seen = []
                for name, T in (('top', T_top), ('side', T_side)):
                    ray = centre_w - np.linalg.inv(T)[:3, 3]
                    angle = np.degrees(np.arccos(abs(normal_w @ ray) / np.linalg.norm(ray)))
                    seen.append(f'{name} {angle:3.0f}')
                found = estimates.get((int(scene.name), int(im), part['obj_id']), [])
                outcome = 'none'
                if found:
                    T = min(found, key=lambda T: float(np.linalg.norm(T[:3, 3] - t_gt)))
                    turns = [S[:3, :3] for S in symmetries_from_models_info(entry).transforms(
                        step_rad=np.radians(1))]
                    R_sym = min((R_gt @ S for S in turns), key=lambda R: _angle_deg(T[:3, :3], R))
                    outcome = ('far' if np.linalg.norm(T[:3, 3] - t_gt) > 0.05 else
                               'ok' if _angle_deg(T[:3, :3], R_sym) < 5 else
                               'wrong: ' + _turn(R_sym, T[:3, :3], thin_o, up_c))
                counts['all'] += 1
                counts['ok'] += outcome == 'ok'
                print(f'scene {int(scene.name)} im {int(im):3d} obj {part["obj_id"]:3d}: '
                      f'face seen at {", ".join(seen)} deg; {outcome}')
    print(f'standing flat parts: {counts["ok"]} of {counts["all"]} ok')


def _filled(points: np.ndarray, centre: np.ndarray, first: np.ndarray, second: np.ndarray
            ) -> np.ndarray:
    """The outline of surface samples seen along the thin axis, its holes filled: (800, 800)
    uint8 at 0.25 mm a pixel about ``centre`` (axes ``first``, ``second``)."""
    import cv2

    q = np.round(np.stack([(points - centre) @ first, (points - centre) @ second], 1)
                 / 2.5e-4).astype(int) + 400
    img = np.zeros((800, 800), np.uint8)
    img[q[:, 1], q[:, 0]] = 1
    img = cv2.morphologyEx(img, cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8))
    contours, _ = cv2.findContours(img, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return cv2.drawContours(np.zeros_like(img), contours, -1, 1, -1)


def parts(models: Path, flat_mm: float) -> None:

    from tlessbot_ros.core.common import centre_of_mass, resting_poses, sample_surface
    from tlessbot_ros.core.pose.flat_turns import outline_frame, outline_half_turns
    from tlessbot_ros.io.models import read_mesh

    info = json.loads((models / 'models_info.json').read_text())
    for key, entry in sorted(info.items(), key=lambda kv: int(kv[0])):
        size = np.array([entry[f'size_{a}'] for a in 'xyz'])
        path = next(iter(models.glob(f'obj_{int(key):02d}.*')), None)
        if size.min() > flat_mm or path is None:
            continue
        vertices, faces = read_mesh(path)
        vertices = vertices / 1000.0   # BOP models: millimetres
        points, _ = sample_surface(vertices, faces, 40000, seed=0)
        centre, first, second, thin, _ = outline_frame(points)

        base = _filled(points, centre, first, second)
        changed = [np.count_nonzero(_filled(points @ T[:3, :3].T + T[:3, 3], centre, first,
                                            second) != base)
                   / np.count_nonzero(base) for T in outline_half_turns(points)]
        com = centre_of_mass(vertices, faces)
        share, tips = 0.0, []
        for T, probability in resting_poses(vertices, faces, entry['diameter'] / 1000):
            thin_w = T[:3, :3] @ thin
            if abs(thin_w[2]) > np.cos(np.radians(70)):
                continue
            share += probability
            low = (vertices @ T[:3, :3].T + T[:3, 3])
            low = low[low[:, 2] < 1e-5, :2]
            com_w = T[:3, :3] @ com + T[:3, 3]
            across = (low - com_w[:2]) @ (thin_w[:2] / np.linalg.norm(thin_w[:2]))
            tips.append(np.degrees(np.arctan2(min(across.max(), -across.min()), com_w[2])))
        print(f'obj {int(key):3d} ({size.min():.2f} mm thin): outline changed by its half '
              f'turns {", ".join(f"{c:.3f}" for c in changed)}; drops standing {share:.3f}, '
              f'toppled by {np.median(tips) if tips else 0:.1f} deg (median)')


def seen(models: Path, flat_mm: float) -> None:
    """Per flat part: the pixels of both cameras of the default rig that its outline's half
    turns change (:func:`~tlessbot_ros.core.pose.observability.changed_pixels`: depth beyond 3
    sigma of the D415 model, or a colour edge moved; fewer than 20: not seen), lying on its
    likeliest face and standing on its likeliest edge, median over 6 yaws."""
    from tlessbot_ros.core.common import (
        default_rig,
        raycasting_scene,
        resting_poses,
        rotation_about_axis,
        sample_surface,
    )
    from tlessbot_ros.core.pose import ObservabilityParams, ViewOfTable
    from tlessbot_ros.core.pose.flat_turns import outline_frame, outline_half_turns
    from tlessbot_ros.core.pose.observability import changed_pixels
    from tlessbot_ros.io.models import read_mesh

    views = [ViewOfTable(c.intrinsics, c.T_world_camera) for c in default_rig().cameras.values()]
    params = ObservabilityParams()
    info = json.loads((models / 'models_info.json').read_text())
    for key, entry in sorted(info.items(), key=lambda kv: int(kv[0])):
        path = next(iter(models.glob(f'obj_{int(key):02d}.*')), None)
        if min(entry[f'size_{a}'] for a in 'xyz') > flat_mm or path is None:
            continue
        vertices, faces = read_mesh(path)
        vertices = vertices / 1000.0
        scene = raycasting_scene(vertices, faces)
        points = sample_surface(vertices, faces, 4000, seed=0)[0]
        thin = outline_frame(points)[3]
        poses = resting_poses(vertices, faces, entry['diameter'] / 1000)
        out = []
        for label, stands in (('lying', False), ('standing', True)):
            T = next((T for T, _ in poses
                      if (abs((T[:3, :3] @ thin)[2]) < np.cos(np.radians(70))) == stands), None)
            if T is None:
                continue
            counts = []
            for turn in outline_half_turns(points):
                per_yaw = []
                for yaw in np.radians(np.arange(0, 180, 30)):
                    Y = np.eye(4)
                    Y[:3, :3] = rotation_about_axis(np.array([0, 0, 1.0]), yaw)
                    A, B = Y @ T, Y @ T @ turn
                    B[2, 3] += (points @ A[2, :3]).min() + A[2, 3] - \
                        (points @ B[2, :3]).min() - B[2, 3]
                    per_yaw.append(sum(changed_pixels(scene, points, A, B, v, params)[2]
                                       for v in views))
                counts.append(int(np.median(per_yaw)))
            errors = []   # what a fit 1 mm off along the face's normal, or 1 deg in yaw, changes
            for shift, yaw_error in ((0.001, 0.0), (0.0, 1.0)):
                per_yaw = []
                for yaw in np.radians(np.arange(0, 180, 30)):
                    Y = np.eye(4)
                    Y[:3, :3] = rotation_about_axis(np.array([0, 0, 1.0]), yaw)
                    A = Y @ T
                    B = A.copy()
                    B[:3, 3] += shift * (A[:3, :3] @ thin) * [1, 1, 0]
                    B[:3, :3] = rotation_about_axis(np.array([0, 0, 1.0]),
                                                    np.radians(yaw_error)) @ B[:3, :3]
                    per_yaw.append(sum(changed_pixels(scene, points, A, B, v, params)[2]
                                       for v in views))
                errors.append(int(np.median(per_yaw)))
            out.append(f'{label} {counts} (1 mm off: {errors[0]}, 1 deg: {errors[1]})')
        print(f'obj {int(key):3d}: px its half turns change (both cameras): {"; ".join(out)}')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('paths', type=Path, nargs='*')
    ap.add_argument('--parts', type=Path, help='a models folder: its flat parts only')
    ap.add_argument('--seen', action='store_true', help='with --parts: the pixels its half '
                    'turns change, lying and standing')
    ap.add_argument('--flat-mm', type=float, default=6.0)
    args = ap.parse_args()
    if args.parts and args.seen:
        seen(args.parts, args.flat_mm)
    elif args.parts:
        parts(args.parts, args.flat_mm)
    else:
        standing(*args.paths, args.flat_mm)


if __name__ == '__main__':
    main()
