"""Where the false parts outside the side image come from: for each pose that
``tlessbot evaluate`` counts as a false part outside the scored camera, how high the top
camera's depth stands over the table around it (rig table; the plane fitted to the top
depth), against the depth cue's heights (``cues.depth_cue``: table below, candidate above)
and the plane fit's noise band (``inlier_sigmas`` x its measured noise x z²); and the same
for the true flat parts (thinnest extent <= 6 mm) of the frame, to compare.
docs/bench/unseen-false-parts.md.

    python scripts/unseen_false_parts_why.py SCENES MODELS ESTIMATES_CSV [FRAME ...]
"""
from __future__ import annotations

import sys
from collections import defaultdict

import numpy as np

from tlessbot_ros.core.common.table_plane import TablePlaneParams, find_table_plane
from tlessbot_ros.core.localise.cues import depth_cue, height_above_table, table_height_m
from tlessbot_ros.core.localise.params import SegmentationParams
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.io.bop_results import read_results
from tlessbot_ros.tools.support.eval_scoring import load_scoring_models
from tlessbot_ros.tools.support.unseen_parts import unscored_false_parts

WINDOW_PX = 12   # half the window read around a pose's centre (a flat part is ~20-40 px)
FLAT_M = 0.006


def _window(top, height: np.ndarray, plane, world_xyz: np.ndarray) -> tuple[str, list]:
    """'p50 / p90 / max (rig) | p90 / max (fitted plane)' of the heights (mm) in the window
    around the top-image projection of ``world_xyz``, and the two p90s."""
    K = top.intrinsics.K
    cam = np.linalg.inv(top.T_world_camera) @ np.append(world_xyz, 1.0)
    u, v, w = K @ cam[:3]
    h, wd = top.depth_m.shape
    # a pose may lie just past the top image's edge: read the nearest window inside
    c, r = int(np.clip(round(u / w), 0, wd - 1)), int(np.clip(round(v / w), 0, h - 1))
    rows, cols = slice(max(r - WINDOW_PX, 0), min(r + WINDOW_PX + 1, h)), \
        slice(max(c - WINDOW_PX, 0), min(c + WINDOW_PX + 1, wd))
    rig = height[rows, cols]
    rig = rig[~np.isnan(rig)] * 1000
    ys, xs = np.mgrid[rows, cols]
    d = top.depth_m[rows, cols]
    ok = np.isfinite(d) & (d > 0)
    pts = (np.linalg.inv(K) @ np.vstack([xs[ok], ys[ok], np.ones(ok.sum())])) * d[ok]
    over = (plane.plane[:3] @ pts + plane.plane[3]) * 1000 if plane is not None else rig
    over = -over if np.median(over) < -0.5 else over   # normal towards the camera
    if not rig.size:
        return 'no depth', []
    p90 = [np.percentile(rig, 90), np.percentile(over, 90)]
    return (f'{np.median(rig):.1f} / {p90[0]:.1f} / {rig.max():.1f} | {p90[1]:.1f} / '
            f'{over.max():.1f}', p90)


def main(argv: list[str]) -> int:
    scenes, models_dir, estimates = argv[:3]
    only = {int(a) for a in argv[3:]}
    side = {im.im_id: im for im in read_split(scenes, 'test_side', load_masks=False)}
    top = {im.im_id: im for im in read_split(scenes, 'test_top', load_masks=False)}
    poses: dict[int, list] = defaultdict(list)
    for est in read_results(estimates):
        poses[est.im_id].append(est)
    models = load_scoring_models(models_dir, {gt.obj_id for im in side.values() for gt in im.gt})
    seg, plane_params = SegmentationParams(), TablePlaneParams()
    print('| frame | what | cue sigma / low / table mm | plane noise@1m / band mm '
          '| p50 / p90 / max mm (rig) | over fitted plane p90 / max mm |')
    print('|---|---|---|---|---|---|')
    summary: dict[str, list] = defaultdict(list)
    for im_id in sorted(i for i in side if not only or i in only):
        s, t = side[im_id], top[im_id]
        false = [p for p in poses.get(im_id, []) if unscored_false_parts(
            s, [p], lambda i: models[i].diameter_m / 2)]
        flat = [gt for gt in s.gt if np.ptp(models[gt.obj_id].vertices, axis=0).min() <= FLAT_M]
        height = height_above_table(t.depth_m, t.intrinsics.K, t.T_world_camera)
        cue = depth_cue(height[::2, ::2], seg)   # at the cue scale, as segmentation reads it
        plane = find_table_plane(t.depth_m, t.intrinsics.K, params=plane_params)
        noise = plane.noise_at_1m_m if plane is not None and plane.noise_at_1m_m else np.nan
        z = float(t.T_world_camera[2, 3])
        head = (f'{cue.sigma_m * 1000:.2f} / '
                f'{max(seg.depth_min_height_m, seg.depth_noise_k * cue.sigma_m) * 1000:.1f} / '
                f'{table_height_m(seg, cue.sigma_m) * 1000:.1f} | {noise * 1000:.2f} / '
                f'{plane_params.inlier_sigmas * noise * z * z * 1000:.1f}')
        for what, items in (('false', [(s.T_world_camera @ p.T_camera_object)[:3, 3]
                                       for p in false]),
                            ('flat part', [(s.T_world_camera @ g.T_camera_object)[:3, 3]
                                           for g in flat])):
            for xyz in items:
                text, p90 = _window(t, height, plane, xyz)
                summary[what].append(p90)
                print(f'| {im_id} | {what} | {head} | {text} |')
    for what, values in summary.items():
        values = np.array([v for v in values if v])
        if values.size:
            print(f'{what}: {len(values)}, p90 over the fitted plane: median '
                  f'{np.median(values[:, 1]):.1f} mm, range {values[:, 1].min():.1f}-'
                  f'{values[:, 1].max():.1f} mm')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
