import numpy as np
import pytest

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    depth_to_points,
    invert_transform,
    look_at,
    make_transform,
    matrix_from_quaternion,
    project_points,
    quaternion_from_matrix,
    rotation_about_axis,
    rotation_angle_deg,
    rpy_from_matrix,
    transform_points,
)


def test_quaternion_round_trip_and_sign():
    rng = np.random.default_rng(3)
    for _ in range(200):
        R = rotation_about_axis(rng.normal(size=3), rng.uniform(-np.pi, np.pi))
        q = quaternion_from_matrix(R)
        assert q[3] >= 0 and np.isclose(np.linalg.norm(q), 1)
        np.testing.assert_allclose(matrix_from_quaternion(q), R, atol=1e-12)


def test_rpy_matches_composition():
    roll, pitch, yaw = 0.3, -0.4, 2.0
    R = (rotation_about_axis([0, 0, 1], yaw) @ rotation_about_axis([0, 1, 0], pitch)
         @ rotation_about_axis([1, 0, 0], roll))
    np.testing.assert_allclose(rpy_from_matrix(R), [roll, pitch, yaw])


def test_transform_inverse_and_angle():
    T = make_transform(rotation_about_axis([1, 2, 3], 0.7), [0.1, -0.2, 0.3])
    np.testing.assert_allclose(invert_transform(T) @ T, np.eye(4), atol=1e-12)
    assert rotation_angle_deg(T[:3, :3], np.eye(3)) == pytest.approx(np.degrees(0.7))


def test_back_projection_reprojects_to_pixels():
    K = np.array([[615.0, 0, 319.5], [0, 615.0, 239.5], [0, 0, 1]])
    depth = np.random.default_rng(0).uniform(0.3, 2.0, (48, 64)).astype(np.float32)
    depth[5, 5] = np.nan
    depth[6, 6] = 0
    points, pixels = depth_to_points(depth, K)
    assert len(points) == 48 * 64 - 2
    uv = project_points(points, K)
    np.testing.assert_allclose(uv[:, ::-1], pixels, atol=1e-3)


def test_look_at_points_z_at_target_and_up_up():
    T = look_at([0, -0.2, 0.6], [0, 0, 0], [0, 0, 1])
    z = T[:3, 2]
    np.testing.assert_allclose(z, -np.array([0, -0.2, 0.6]) / np.linalg.norm([0, -0.2, 0.6]))
    assert T[:3, 1] @ [0, 0, 1] < 0  # image y (down) points away from world up
    centre = transform_points(invert_transform(T), np.zeros((1, 3)))
    np.testing.assert_allclose(centre[0, :2], 0, atol=1e-12)


def test_bad_intrinsics_raise():
    with pytest.raises(ValueError, match='3x3'):
        CameraIntrinsics(width=1, height=1, K=np.eye(2))
    with pytest.raises(ValueError, match='focal'):
        CameraIntrinsics(width=1, height=1, K=np.zeros((3, 3)))


@pytest.mark.parametrize('region', [(slice(100, 160), slice(200, 290)),
                                    (slice(0, 5), slice(630, 640)), (slice(0, 0), slice(0, 0))])
def test_masked_back_projection_is_the_masked_part_of_the_whole(region):
    from tlessbot_ros.core.common import depth_to_points

    rng = np.random.default_rng(1)
    depth = rng.uniform(0.3, 1.0, (480, 640)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0.0
    depth[rng.random(depth.shape) < 0.05] = np.nan
    K = np.array([[615.0, 0, 321.37], [0, 615.0, 239.81], [0, 0, 1]])
    mask = np.zeros(depth.shape, bool)
    mask[region] = True
    mask[rng.random(depth.shape) < 0.2] = False
    points, pixels = depth_to_points(depth, K, mask=mask)
    all_points, all_pixels = depth_to_points(depth, K)
    keep = mask[all_pixels[:, 0], all_pixels[:, 1]]
    np.testing.assert_array_equal(points, all_points[keep])      # same values, same order
    np.testing.assert_array_equal(pixels, all_pixels[keep])
    assert points.dtype == np.float32 and pixels.shape == (int(keep.sum()), 2)


def test_mask_box_is_the_tight_box_and_empty_for_an_empty_mask():
    from tlessbot_ros.core.common import mask_box

    mask = np.zeros((20, 30), bool)
    assert mask_box(mask) == (0, 0, 0, 0)
    mask[3:7, 10:25] = True
    mask[12, 4] = True
    assert mask_box(mask) == (4, 3, 21, 10)
