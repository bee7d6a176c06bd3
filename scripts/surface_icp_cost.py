"""CPU a call of the depth turn's ICP: Open3D's registration_icp (before 490690f) against
flat_turns.refit_to_surface (fixed-order numpy), in one run, on the parts of a templates file.

    python scripts/surface_icp_cost.py [TEMPLATES.npz]   (default: the bench's generated parts)

Each part: 600 samples of its mesh 0.6 m in front of the camera, started 3 degrees and 1.5 mm
off. Prints the CPU a call of each (best of 3 rounds of 5 calls a part), their ratio, and the
largest difference between the poses they return.
"""
from __future__ import annotations

import sys
import time

import numpy as np
import open3d as o3d

from tlessbot_ros.core.common import rotation_about_axis, sample_surface
from tlessbot_ros.core.pose import flat_turns
from tlessbot_ros.core.pose.database import ObjectTemplates, TemplateDatabase


def open3d_refit(obj: ObjectTemplates, T: np.ndarray, points_c: np.ndarray) -> np.ndarray:
    """refit_to_surface as it was: Open3D's point-to-plane registration_icp."""
    def surface() -> o3d.geometry.PointCloud:
        points, normals = sample_surface(obj.mesh_vertices, obj.mesh_faces, 3000, seed=0)
        cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        cloud.normals = o3d.utility.Vector3dVector(normals)
        return cloud

    reg = o3d.pipelines.registration
    T_inv = np.linalg.inv(T)
    source = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(
        points_c @ T_inv[:3, :3].T + T_inv[:3, 3]))
    result = reg.registration_icp(source, obj.derived('open3d_surface', surface), 0.003,
                                  np.eye(4), reg.TransformationEstimationPointToPlane(),
                                  reg.ICPConvergenceCriteria(max_iteration=20))
    return np.asarray(T @ np.linalg.inv(result.transformation))


def main() -> None:
    path = sys.argv[1] if len(sys.argv) > 1 else '/work/bench/parts/g/templates.npz'
    cases = []
    for obj in TemplateDatabase.load(path).objects.values():
        if obj.mesh_vertices is None:
            continue
        points, _ = sample_surface(obj.mesh_vertices, obj.mesh_faces, 600, seed=1)
        start = np.eye(4)
        start[:3, :3] = rotation_about_axis([0.2, 0.1, 1.0], np.radians(3.0))
        start[:3, 3] = [0.001, -0.001, 0.6005]
        cases.append((obj, start, points + [0.0, 0.0, 0.6]))
    ways = {'open3d': open3d_refit, 'numpy': flat_turns.refit_to_surface}
    for refit in ways.values():
        refit(*cases[0])   # the surfaces are built once per part, as in the pose node
    best = {}
    for name, refit in list(ways.items()) * 3:
        start_cpu = time.process_time()
        for case in cases * 5:
            refit(*case)
        per_call = (time.process_time() - start_cpu) / (5 * len(cases))
        best[name] = min(best.get(name, np.inf), per_call)
    ratio = best['numpy'] / best['open3d']
    print(f'{5 * len(cases)} calls: open3d {best["open3d"] * 1e3:.2f} ms, numpy '
          f'{best["numpy"] * 1e3:.2f} ms a call; numpy / open3d {ratio:.2f}')
    gap = max(np.abs(open3d_refit(*c) - flat_turns.refit_to_surface(*c)).max() for c in cases)
    print(f'largest difference between their poses: {gap:.1e}')


if __name__ == '__main__':
    main()
