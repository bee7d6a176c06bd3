"""Per ground-truth part, the pose measures of several `tlessbot evaluate` outputs side by side.

For every scored part (visible fraction >= 0.3) of the frames with depth of a BOP set, each
run's estimate (matched as evaluate matches them) is scored as evaluate scores it: 5 cm / 5°,
VSD (< 0.3), ADD-S (< 0.1 d), MSSD error; one row per part, the runs' columns side by side,
rows where the runs differ marked (docs/bench/real-box-regression.md).

    PYTHONPATH=. python scripts/real_box_instances.py --dataset $D --models $D/models \
        RUN_A/estimates.csv RUN_B/estimates.csv [...]
"""
from __future__ import annotations

import argparse
from pathlib import Path

from tlessbot_ros.core.metrics import adds, is_correct_cm_deg, mssd, pose_error, vsd
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.io.bop_results import read_results
from tlessbot_ros.tools.support.eval_scoring import (
    ADDS_THRESHOLD,
    MIN_VISIB_FRACT,
    load_scoring_models,
    match_poses,
)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True)
    parser.add_argument('--models', type=Path, required=True)
    parser.add_argument('--split', default='test')
    parser.add_argument('runs', type=Path, nargs='+', help='estimates.csv of each run')
    args = parser.parse_args()
    runs = [read_results(path) for path in args.runs]
    images = [im for im in read_split(args.dataset, args.split) if im.depth_m is not None]
    models = load_scoring_models(args.models, {gt.obj_id for im in images for gt in im.gt})
    names = ' | '.join(f'run {k}: 5°5cm / VSD / ADD-S / MSSD mm' for k in range(len(runs)))
    print(f'| scene/im | gt | obj | visib | {names} | differs |')
    print('|' + '---|' * (5 + len(runs)))
    for image in images:
        matched = [match_poses(image, [e for e in run if (e.scene_id, e.im_id) ==
                                       (image.scene_id, image.im_id)], models) for run in runs]
        for k, gt in enumerate(image.gt):
            if gt.visib_fract is None or gt.visib_fract < MIN_VISIB_FRACT:
                continue
            cells = [_cell(match.get(k), gt, models[gt.obj_id], image) for match in matched]
            flags = [c.split(' / ')[:3] for c in cells]
            differs = '**yes**' if any(f != flags[0] for f in flags) else ''
            print(f'| {image.scene_id}/{image.im_id} | {k} | {gt.obj_id} | '
                  f'{gt.visib_fract:.2f} | {" | ".join(cells)} | {differs} |')


def _cell(estimate, gt, model, image) -> str:
    """'ok/no' for 5 cm 5°, the VSD error, 'ok/no' for ADD-S, the MSSD error (mm)."""
    if estimate is None:
        return 'none'
    T, T_gt = estimate.T_camera_object, gt.T_camera_object
    error = pose_error(T, T_gt, model.symmetries)
    right = is_correct_cm_deg(error)
    vsd_error = vsd(T, T_gt, image.depth_m, image.intrinsics, model.renderer)[0]
    adds_ok = adds(T, T_gt, model.vertices) < ADDS_THRESHOLD * model.diameter_m
    mssd_mm = 1000 * mssd(T, T_gt, model.points, model.symmetry_stack)
    return (f'{"ok" if right else "no"} {error.rotation_deg:.0f}° / {vsd_error:.3f} / '
            f'{"ok" if adds_ok else "no"} / {mssd_mm:.1f}')


if __name__ == '__main__':
    main()
