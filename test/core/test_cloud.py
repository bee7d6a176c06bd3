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


def _open3d_keep(points: np.ndarray, neighbors: int, std_ratio: float) -> np.ndarray:
    keep = np.zeros(len(points), bool)
    _, index = cloud.to_o3d(points).remove_statistical_outlier(nb_neighbors=neighbors,
                                                               std_ratio=std_ratio)
    keep[np.asarray(index, np.int64)] = True
    return keep


def _odd_cloud(rng: np.random.Generator, case: int) -> np.ndarray:
    """Clouds of the shapes the pose stage sees, and of the shapes that trip a k-NN search."""
    n = int(rng.integers(52, 1500))
    centre = rng.uniform([-0.2, -0.2, 0.4], [0.2, 0.2, 1.2])
    if case == 0:    # a blob and a few far points
        points = np.concatenate([rng.normal(0, 0.01, (n, 3)),
                                 rng.uniform(-0.2, 0.2, (int(rng.integers(0, 20)), 3))])
    elif case == 1:  # a part's faces seen by a depth camera, voxelised as the pose stage does
        faces = rng.uniform(-0.03, 0.03, (4 * n, 3))
        faces[np.arange(len(faces)), rng.integers(0, 3, len(faces))] = 0.03
        points, _ = cloud.voxel_downsample(faces + rng.normal(0, 0.001, faces.shape), 0.004)
    elif case == 2:  # a regular grid: many equal distances at the k-th neighbour
        side = int(np.ceil(n ** (1 / 3)))
        points = 0.002 * np.stack(np.meshgrid(*[np.arange(side)] * 3), -1).reshape(-1, 3)
    elif case == 3:  # repeated points (a mean distance of 0 is never kept)
        base = rng.normal(0, 0.01, (n // 4, 3))
        points = np.concatenate([base, np.repeat(base[:3], 60, axis=0), base[:n // 8]])
    elif case == 4:  # flat on one axis, rows of equal coordinates
        points = np.column_stack([rng.uniform(-0.05, 0.05, n), np.zeros(n),
                                  np.round(rng.uniform(0, 0.05, n), 3)])
    else:            # a line with a gap and a cluster
        t = np.concatenate([rng.uniform(0, 0.1, n), rng.uniform(0.3, 0.31, 30)])
        points = np.column_stack([t, 0.5 * t, rng.normal(0, 1e-4, len(t))])
    return rng.permutation(points) + centre


def test_statistical_outliers_keep_exactly_what_open3d_keeps():
    rng = np.random.default_rng(20)
    differing, kept_share = [], []
    for trial in range(600):
        points = _odd_cloud(rng, trial % 6)
        neighbors = int(rng.choice([1, 2, 5, 20, 50, 50, 50]))
        std_ratio = float(rng.choice([0.3, 1.0, 2.0, 2.0, 3.5]))
        if len(points) <= neighbors:
            continue
        keep = cloud.remove_statistical_outliers(points, neighbors=neighbors,
                                                 std_ratio=std_ratio)
        expected = _open3d_keep(points, neighbors, std_ratio)
        kept_share.append(expected.mean())
        if not np.array_equal(keep, expected):
            differing.append((trial, neighbors, std_ratio, int((keep != expected).sum())))
    assert differing == []
    assert 0.3 < np.mean(kept_share) < 1.0   # the cases do drop points


def test_mean_neighbour_distances_are_open3d_bits():
    """Each point's mean distance equals, bit for bit, the one made from Open3D's own k-NN
    squared distances (summed as Open3D sums them)."""
    import math

    import open3d as o3d

    from tlessbot_ros.core.pose.outlier_kernels import mean_neighbour_distances

    rng = np.random.default_rng(21)
    for trial in range(30):
        points = _odd_cloud(rng, trial % 6)
        k = 50
        tree = o3d.geometry.KDTreeFlann(cloud.to_o3d(points))
        means = mean_neighbour_distances(np.ascontiguousarray(points, np.float64), k)
        for i in rng.choice(len(points), 40, replace=False):
            _, _, squared = tree.search_knn_vector_3d(points[i], k)
            total = 0.0
            for d2 in squared:
                total += math.sqrt(d2)
            assert means[i] == total / len(squared)


def test_statistical_outliers_bad_arguments():
    points = np.zeros((10, 3))
    with pytest.raises(ValueError, match='std_ratio'):
        cloud.remove_statistical_outliers(points, neighbors=3, std_ratio=0.0)
    with pytest.raises(ValueError, match='neighbors'):
        cloud.remove_statistical_outliers(points, neighbors=0)
    assert cloud.remove_statistical_outliers(points[:3], neighbors=5).all()


def test_smallest_sorted_is_the_head_of_a_sort():
    """The bucket selection of the outlier kernel gives the m smallest distances in ascending
    order, as a full sort does: random values, many ties, zeros, one value, bounds far above
    the values, an infinite distance, and a bound so small that its reciprocal overflows."""
    from numba import njit

    from tlessbot_ros.core.pose.outlier_kernels import _smallest_sorted

    call = njit(lambda found, count, m, bound, starts, out:
                _smallest_sorted(found, count, m, bound, starts, out))
    rng = np.random.default_rng(22)
    for trial in range(3000):
        count = int(rng.integers(1, 300))
        kind = trial % 6
        if kind == 0:
            found = rng.uniform(0, 1e-4, count)
        elif kind == 1:      # few distinct values: ties at the m-th
            found = rng.integers(0, 4, count) * 1e-5
        elif kind == 2:      # squared distances of points on a grid
            found = (rng.integers(0, 5, (count, 3)) ** 2).sum(axis=1) * 4e-6
        elif kind == 3:      # all zero (repeated points)
            found = np.zeros(count)
        elif kind == 4:      # an infinite distance among others
            found = rng.uniform(0, 1.0, count)
            found[rng.integers(count)] = np.inf
        else:                # tiny values, tiny bound
            found = rng.uniform(0, 1e-310, count)
        m = int(rng.integers(1, count + 1))
        bound = float(rng.choice([found.max(), 2.5 * found.max(), np.inf, 1e-310]))
        if not bound >= found.max():
            bound = np.inf
        out = np.full(count, -1.0)
        filled = call(found.copy(), count, m, bound, np.empty(count + 1, np.int64), out)
        assert m <= filled <= count
        np.testing.assert_array_equal(out[:m], np.sort(found)[:m])
