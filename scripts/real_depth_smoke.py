"""Real RealSense frames without part ground truth through the table plane and the pose stage.

Checks that nothing breaks on real depth (docs/bench/real-pose.md): for each frame, the table
plane found in the depth and its angle to the AprilTag grid (ViSP RBT sequence, ``--rbt``: the
grid is a board standing on the desk, so the desk plane is at right angles to it and a plane
parallel to it is the board), and the pose stage run on a box around the image centre with
every part of ``--templates`` as a candidate (no crash, points, time).

    PYTHONPATH=. python scripts/real_depth_smoke.py --rbt ../shared/data/visp_images_rbt_sequence \
        --d435 ../shared/data/visp_realsense_tutorial_data --templates T.npz
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import SIDE, CameraIntrinsics
from tlessbot_ros.core.common.table_plane import TablePlaneParams, find_table_plane
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import TemplateDatabase


def _rbt_frames(root: Path):
    cam = json.loads((root / 'sequence' / 'cam.json').read_text())
    K = np.array([[cam['px'], 0, cam['u0']], [0, cam['py'], cam['v0']], [0, 0, 1.0]])
    grid = json.loads((root / 'sequence' / 'apriltag_data.json').read_text())['grid']
    import cv2
    for path in sorted((root / 'sequence').glob('depth_image_*.npz')):
        index = int(path.stem.split('_')[-1])
        depth = np.load(path, allow_pickle=False)['data'].astype(np.float32) * 1e-3
        rgb = cv2.imread(str(path.with_name(f'color_image_{index:04d}.png')))[..., ::-1]
        yield f'rbt {index:04d}', rgb, depth, K, np.asarray(grid[index], np.float64)


def _d435_frames(root: Path):
    folder = root / 'computer-vision' / 'd435_align_depth'
    raw = (folder / 'depth_image_0000.bin').read_bytes()
    h, w = np.frombuffer(raw[:8], '<u4')
    depth = np.frombuffer(raw[8:], '<u2').reshape(h, w).astype(np.float32) * 1e-3
    K = np.array([[605.1467, 0, 325.5325], [0, 604.7915, 244.9508], [0, 0, 1.0]])
    import cv2
    rgb = cv2.imread(str(folder / 'color_image_0000.jpg'))[..., ::-1]
    yield 'd435 align 0000', rgb, depth, K, None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rbt', type=Path)
    parser.add_argument('--d435', type=Path)
    parser.add_argument('--templates', type=Path, required=True)
    parser.add_argument('--noise-at-1m', type=float, default=TablePlaneParams().noise_at_1m_m,
                        help='TablePlaneParams.noise_at_1m_m, m')
    args = parser.parse_args()
    database = TemplateDatabase.load(args.templates)
    frames = []
    if args.rbt:
        frames += list(_rbt_frames(args.rbt))
    if args.d435:
        frames += list(_d435_frames(args.d435))
    plane_params = TablePlaneParams(noise_at_1m_m=args.noise_at_1m)
    pipeline = PerceptionPipeline(templates=database, table_plane=plane_params)
    print('| frame | valid depth | table: camera height m, inliers | angle to the tag board, '
          'deg: surface | pose stage: points, parts fitted, ms |')
    print('|---|---|---|---|---|')
    desks = 0
    for name, rgb, depth, K, cMg in frames:
        h, w = depth.shape
        depth = np.where(depth > 0, depth, np.nan)
        table = find_table_plane(depth, K, params=plane_params)
        grid = 'n/a'
        if table is not None and cMg is not None:
            angle = np.degrees(np.arccos(np.clip(abs(cMg[:3, 2] @ table.normal), -1, 1)))
            desks += angle > 45
            grid = f'{angle:.1f}: ' + ('desk' if angle > 45 else 'board')
        pipeline = pipeline.replace()   # a fresh table tracker: the frames are far apart
        view = ViewInput(rgb, depth, CameraIntrinsics(width=w, height=h, K=K), None)
        labels = np.zeros((h, w), np.uint16)
        labels[h // 3:2 * h // 3, w // 3:2 * w // 3] = 1
        t0 = time.perf_counter()
        found = pipeline.estimate_poses({SIDE: view}, {SIDE: labels},
                                        {1: tuple(sorted(database.objects))}, box_mode=True)
        ms = 1e3 * (time.perf_counter() - t0)
        fitted = sum(d.pose is not None for d in found)
        points = found[0].n_points if found else 0
        plane = 'none' if table is None else \
            f'{table.camera_height_m:.3f}, {table.inlier_share:.2f}'
        print(f'| {name} | {np.mean(np.isfinite(depth)):.2f} | {plane} | {grid} '
              f'| {points}, {fitted}, {ms:.0f} |')
    print(f'\ndesk found in {desks} of {sum(f[4] is not None for f in frames)} RBT frames')


if __name__ == '__main__':
    main()
