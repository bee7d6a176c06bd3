"""Flat parts turned over: the flip check finds the side that lies up from the depth alone."""
import numpy as np
import open3d as o3d

from tlessbot_ros.core.common import make_transform, raycasting_scene, rotation_about_axis
from tlessbot_ros.core.pose import FlipCheck, half_turns
from tlessbot_ros.tools.support.part_generator import mesh_part, part_shapes


def _mesh(name):
    sdf, (low, high) = part_shapes()[name]
    vertices, faces = mesh_part(sdf, low, high, spacing_mm=0.5)
    return vertices / 1000.0, faces


def _seen(mesh, T_camera_object, pixels=160, focal=615.0):
    """The ROI cloud a camera sees of the part (ray-cast, noise-free), optical frame."""
    vertices, faces = mesh
    moved = vertices @ T_camera_object[:3, :3].T + T_camera_object[:3, 3]
    u, v = np.meshgrid(np.arange(pixels) - pixels / 2, np.arange(pixels) - pixels / 2)
    rays = np.stack([u.ravel() / focal, v.ravel() / focal, np.ones(u.size)], axis=1)
    rays = np.hstack([np.zeros_like(rays), rays]).astype(np.float32)
    hits = raycasting_scene(moved, faces).cast_rays(o3d.core.Tensor(rays))['t_hit'].numpy()
    keep = np.isfinite(hits)
    return rays[keep, 3:] * hits[keep, None]


def _pose():
    R = rotation_about_axis(np.array([1.0, 0.0, 0.0]), np.radians(160.0)) @ \
        rotation_about_axis(np.array([0.0, 0.0, 1.0]), np.radians(25.0))
    return make_transform(R, [0.0, 0.0, 0.55])


def test_a_turned_over_plate_is_turned_back():
    mesh = _mesh('plate_holes2')
    check = FlipCheck({5: mesh})
    assert 5 in check and len(check.turns[5]) == 3
    T = _pose()
    points = _seen(mesh, T)
    same, vote = check.resolve(5, T, points)
    assert vote == 0.0 and np.allclose(same, T)
    for turn in check.turns[5]:
        found, vote = check.resolve(5, T @ turn, points)
        assert vote > 0.01
        assert np.linalg.norm(found[:3, 3] - T[:3, 3]) < 1e-3          # 1 mm (refitted)
        assert np.degrees(np.arccos(np.clip((np.trace(found[:3, :3].T @ T[:3, :3]) - 1) / 2,
                                            -1, 1))) < 1.0


def test_symmetric_and_bulky_parts_are_left_alone():
    assert half_turns(_mesh('block_drilled')[0]) == []        # 40 x 30 x 20: not flat
    disc = _mesh('disc_flange')      # flat, but its half turns are symmetries
    check = FlipCheck({4: disc})
    T = _pose()
    found, vote = check.resolve(4, T, _seen(disc, T))
    assert vote == 0.0 and np.allclose(found, T)
