"""The depth turn's point-to-plane ICP (flat_turns.point_to_plane_icp): the same input gives
the same pose to the last bit, and it is the registration Open3D's registration_icp computes."""
from __future__ import annotations

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from tlessbot_ros.core.common import rotation_about_axis
from tlessbot_ros.core.pose.flat_turns import point_to_plane_icp


def _wavy_surface(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Target samples and normals of a wavy 10 cm patch, and a moved, noisy subset of them."""
    rng = np.random.default_rng(seed)
    uv = rng.uniform(-0.05, 0.05, (8000, 2))
    points = np.c_[uv, 0.01 * np.sin(40 * uv[:, 0]) * np.cos(30 * uv[:, 1])]
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    cloud.estimate_normals()
    source = points[::5] + rng.normal(0.0, 0.0003, (len(points[::5]), 3))
    turn = rotation_about_axis([0.3, -0.2, 1.0], np.radians(2.0))
    return points, np.asarray(cloud.normals), source @ turn.T + [0.001, 0.0015, -0.0005]


def test_same_input_same_pose_to_the_last_bit() -> None:
    target, normals, source = _wavy_surface()
    tree = cKDTree(target)
    first = point_to_plane_icp(source, tree, normals, 0.003, 20)
    for _ in range(5):
        assert np.array_equal(point_to_plane_icp(source, tree, normals, 0.003, 20), first)


def test_agrees_with_open3d_registration_icp() -> None:
    target, normals, source = _wavy_surface(1)
    reg = o3d.pipelines.registration
    target_cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(target))
    target_cloud.normals = o3d.utility.Vector3dVector(normals)
    theirs = reg.registration_icp(
        o3d.geometry.PointCloud(o3d.utility.Vector3dVector(source)), target_cloud, 0.003,
        np.eye(4), reg.TransformationEstimationPointToPlane(),
        reg.ICPConvergenceCriteria(max_iteration=20)).transformation
    ours = point_to_plane_icp(source, cKDTree(target), normals, 0.003, 20)
    assert np.abs(ours - np.asarray(theirs)).max() < 1e-9
    # and it did move the cloud: the start is 2 degrees and 2 mm off
    assert np.abs(ours[:3, 3]).max() > 5e-4


def test_no_correspondence_leaves_the_pose() -> None:
    target, normals, source = _wavy_surface()
    far = source + [1.0, 0.0, 0.0]
    assert np.array_equal(point_to_plane_icp(far, cKDTree(target), normals, 0.003, 20),
                          np.eye(4))
    assert np.array_equal(point_to_plane_icp(np.zeros((0, 3)), cKDTree(target), normals,
                                             0.003, 20), np.eye(4))
