"""core.cloud: back-projection, crops, background subtraction, outliers, voxels, normals."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import CameraIntrinsics
from tlessbot_ros.core.pose import cloud


def _intrinsics(w: int = 80, h: int = 60) -> CameraIntrinsics:
    K = np.array([[70.0, 0, (w - 1) / 2], [0, 70.0, (h - 1) / 2], [0, 0, 1]])
    return CameraIntrinsics(width=w, height=h, K=K)


def _plane(rng: np.random.Generator, n: int, z: float = 0.0) -> np.ndarray:
    return np.column_stack([rng.uniform(-0.2, 0.2, (n, 2)), np.full(n, z)])


def test_rgbd_to_cloud_plane_and_colours():
    K = _intrinsics()
    depth = np.full((60, 80), 0.5, np.float32)
    depth[0, 0] = 0.0
    depth[1, 1] = np.nan
    rgb = np.zeros((60, 80, 3), np.uint8)
    rgb[..., 0] = 255
    points, colours = cloud.rgbd_to_cloud(depth, K, rgb=rgb)
    assert points.shape == (60 * 80 - 2, 3)
    np.testing.assert_allclose(points[:, 2], 0.5)
    np.testing.assert_allclose(colours[:, 0], 1.0)
    # The principal point back-projects onto the optical axis.
    centre = cloud.rgbd_to_cloud(depth, K, mask=np.pad(np.ones((1, 1), bool),
                                                       ((29, 30), (39, 40))))[0]
    assert np.allclose(centre[0, :2], [(39 - 39.5) * 0.5 / 70, (29 - 29.5) * 0.5 / 70])
    with pytest.raises(ValueError, match='does not match'):
        cloud.rgbd_to_cloud(depth[:10], K)


def test_roi_cloud_uses_the_mask_only():
    K = _intrinsics()
    depth = np.full((60, 80), 0.8, np.float32)
    mask = np.zeros((60, 80), bool)
    mask[10:20, 30:40] = True
    assert len(cloud.roi_cloud(depth, mask, K)) == 100
    with pytest.raises(ValueError, match='mask shape'):
        cloud.roi_cloud(depth, mask[:5], K)


def test_crop_box_with_transform():
    points = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.5, 0.5, 0.5]])
    inside = cloud.crop_box(points, [-0.1, -0.1, -0.1], [0.6, 0.6, 0.6])
    assert inside.tolist() == [True, False, True]
    T = np.eye(4)
    T[0, 3] = -1.0  # shift x by -1: now the second point is at the origin
    assert cloud.crop_box(points, [-0.1] * 3, [0.1] * 3, T_box_points=T).tolist() == \
        [False, True, False]
    with pytest.raises(ValueError, match='bounds'):
        cloud.crop_box(points, [1, 1, 1], [0, 0, 0])


def test_background_subtraction_keeps_the_object():
    rng = np.random.default_rng(0)
    table_scene = _plane(rng, 3000)
    box = rng.uniform([-0.02, -0.02, 0.005], [0.02, 0.02, 0.04], (400, 3))
    background = _plane(rng, 3000)
    scene = np.concatenate([table_scene, box])
    keep = cloud.subtract_background(scene, background)
    assert keep[:3000].mean() < 0.01          # the table went
    assert keep[3000:].mean() > 0.95          # the object stayed


def test_statistical_outliers_removed():
    rng = np.random.default_rng(1)
    blob = rng.normal(0, 0.01, (500, 3))
    far = rng.uniform(0.3, 0.5, (5, 3))
    keep = cloud.remove_statistical_outliers(np.concatenate([blob, far]), neighbors=50)
    assert not keep[500:].any()
    assert keep[:500].mean() > 0.9


def test_voxel_downsample_and_normals_face_camera():
    rng = np.random.default_rng(2)
    points = _plane(rng, 5000, z=0.6)          # a plane 0.6 m in front of the camera
    down, _ = cloud.voxel_downsample(points, 0.01)
    assert 1000 < len(down) < 2000             # 0.4 m x 0.4 m at 1 cm: about 1600 cells
    normals = cloud.estimate_normals(down, radius_m=0.02)
    np.testing.assert_allclose(normals[:, 2], -1.0, atol=1e-6)   # towards the origin
    pts, nrm = cloud.preprocess_roi(points, voxel_size_m=0.01)
    assert len(pts) == len(nrm) and np.all(nrm[:, 2] < -0.99)
    with pytest.raises(ValueError):
        cloud.voxel_downsample(points, 0.0)
