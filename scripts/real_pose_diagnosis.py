"""Does the ground truth fit the real depth, and what is the best the depth allows?

For every ground-truth part of the frames with depth of a BOP set (docs/bench/real-pose.md):
all parts are ray-cast at their ground-truth poses with the set's camera matrix, and over each
part's visible pixels the real depth is compared with the rendered one (median and MAD of real
- rendered, share within 5 mm); the part's lowest point is measured from the table plane found
in the depth. Then ICP (the pose stage's refiner) starts at the ground truth on the part's own
visible pixels and the pose it converges to, the depth's optimum near the ground truth, is
written as a BOP results file: `tlessbot evaluate --poses` scores it, the ceiling of what a
pose stage fitting this depth can reach against this ground truth.

    PYTHONPATH=. python scripts/real_pose_diagnosis.py --dataset $D --templates T.npz \
        --out depth-optimum_sygrid-test.csv
    tlessbot evaluate --dataset $D --models $D/models --poses depth-optimum_sygrid-test.csv
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import MeshRenderer, transform_points
from tlessbot_ros.core.common.table_plane import find_table_plane, table_frame_from_plane
from tlessbot_ros.core.pose import PoseEstimator, TemplateDatabase, roi_cloud
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.io.bop_results import BopEstimate, write_results
from tlessbot_ros.io.models import read_mesh


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True)
    parser.add_argument('--templates', type=Path, required=True,
                        help="templates of the set's parts (e.g. the parts folder of "
                             '`tlessbot evaluate --models`)')
    parser.add_argument('--split', default='test')
    parser.add_argument('--units', type=float, default=1e-3, help='model units, m (mm: 1e-3)')
    parser.add_argument('--out', type=Path, required=True, help='BOP results CSV to write')
    args = parser.parse_args()
    database = TemplateDatabase.load(args.templates)
    estimator = PoseEstimator(database)
    meshes = {}
    for obj_id in database.objects:
        vertices, faces = read_mesh(args.dataset / 'models' / f'obj_{obj_id:06d}.ply')
        meshes[obj_id] = (vertices * args.units, faces)
    print('| frame | part | obj | visible px | real - rendered median mm | MAD mm | within 5 mm '
          '| lowest point above table mm | ICP from GT moves mm |')
    print('|---|---|---|---|---|---|---|---|---|')
    estimates = []
    for image in read_split(args.dataset, args.split):
        if image.depth_m is None:
            continue
        renderer = MeshRenderer()
        for gt in image.gt:
            renderer.add_mesh(*meshes[gt.obj_id], gt.T_camera_object)
        rendered = renderer.render(image.intrinsics, np.eye(4))
        table = find_table_plane(image.depth_m, image.intrinsics.K)
        T_world_camera = None if table is None else table_frame_from_plane(table.plane)
        for k, gt in enumerate(image.gt):
            visible = rendered.instance == k
            real = image.depth_m[visible]
            valid = np.isfinite(real) & (real > 0)
            residual = 1e3 * (real[valid] - rendered.depth_m[visible][valid])
            if len(residual) == 0:
                continue
            median = float(np.median(residual))
            lowest = np.nan if T_world_camera is None else 1e3 * transform_points(
                T_world_camera @ gt.T_camera_object, meshes[gt.obj_id][0])[:, 2].min()
            obj = database[gt.obj_id]
            points = roi_cloud(image.depth_m, visible, image.intrinsics).astype(np.float64)
            moved = np.nan
            if len(points) >= 30:
                scene = estimator._prepare(points, obj, 1.0, {})
                T = estimator.refiner.icp_batch(scene, obj, gt.T_camera_object[None],
                                                iterations=30, points=len(scene))[0]
                moved = 1e3 * np.linalg.norm(T[:3, 3] - gt.T_camera_object[:3, 3])
                estimates.append(BopEstimate(image.scene_id, image.im_id, gt.obj_id, 1.0, T,
                                             0.0))
            print(f'| {image.im_id} | {k} | {gt.obj_id} | {int(visible.sum())} | {median:+.1f} '
                  f'| {np.median(np.abs(residual - median)):.1f} '
                  f'| {np.mean(np.abs(residual) < 5):.2f} | {lowest:+.1f} | {moved:.1f} |')
    write_results(args.out, estimates)
    print(f'\n{len(estimates)} depth-optimum poses -> {args.out}')


if __name__ == '__main__':
    main()
