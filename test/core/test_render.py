import numpy as np
import pytest

from tlessbot_ros.core.common import (
    NO_HIT,
    CameraIntrinsics,
    MeshRenderer,
    depth_to_points,
    look_at,
    transform_points,
)


def _box(size: float):
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * size / 2
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return corners, faces


def test_plane_depth_and_box_surface():
    renderer = MeshRenderer()
    plane = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float)
    renderer.add_mesh(plane, np.array([[0, 1, 2], [0, 2, 3]]))
    vertices, faces = _box(0.1)
    T_world_box = np.eye(4)
    T_world_box[:3, 3] = [0.02, 0.01, 0.05]
    assert renderer.add_mesh(vertices, faces, T_world_box) == 1
    intrinsics = CameraIntrinsics(width=160, height=120,
                                  K=np.array([[150.0, 0, 79.5], [0, 150.0, 59.5], [0, 0, 1]]))
    T_world_camera = look_at([0, 0, 1.0], [0, 0, 0], [0, 1, 0])
    result = renderer.render(intrinsics, T_world_camera)
    assert (result.instance != NO_HIT).all()  # the plane fills the view
    box = result.instance == 1
    assert box.sum() > 100
    # The top of the box is 0.9 m away, the table 1.0 m.
    np.testing.assert_allclose(result.depth_m[box], 0.9, atol=1e-5)
    np.testing.assert_allclose(result.depth_m[result.instance == 0], 1.0, atol=1e-5)
    # Back-projected box pixels lie on the top face (world z = 0.1), within the box.
    points_c, _ = depth_to_points(result.depth_m, intrinsics.K, mask=box)
    points_w = transform_points(T_world_camera, points_c)
    np.testing.assert_allclose(points_w[:, 2], 0.1, atol=1e-5)
    assert np.all(np.abs(points_w[:, 0] - 0.02) <= 0.05 + 2e-3)
    # Normals face the camera.
    np.testing.assert_allclose(result.normals_c[box], [[0, 0, -1]] * int(box.sum()), atol=1e-5)


def test_empty_scene_renders_nothing():
    intrinsics = CameraIntrinsics(width=8, height=6, K=np.diag([10.0, 10.0, 1.0]))
    result = MeshRenderer().render(intrinsics, np.eye(4))
    assert (result.depth_m == 0).all() and (result.instance == NO_HIT).all()
    assert result.depth_m.shape == (6, 8)


@pytest.mark.parametrize('seed', range(3))
def test_depth_is_along_optical_axis(seed):
    rng = np.random.default_rng(seed)
    renderer = MeshRenderer()
    big = 10.0
    renderer.add_mesh(np.array([[-big, -big, 0], [big, -big, 0], [big, big, 0], [-big, big, 0]]),
                      np.array([[0, 1, 2], [0, 2, 3]]))
    eye = np.array([rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3), rng.uniform(0.5, 1.5)])
    T = look_at(eye, [0, 0, 0], [0, 1, 0] if seed else [1, 0, 0])
    intrinsics = CameraIntrinsics(width=64, height=48,
                                  K=np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]]))
    result = renderer.render(intrinsics, T)
    points_w = transform_points(T, depth_to_points(result.depth_m, intrinsics.K)[0])
    np.testing.assert_allclose(points_w[:, 2], 0.0, atol=1e-4)
