"""A flat part standing on an edge: the side camera sees its face at 70° or more, where a hole
through a few millimetres of plate is blind, but its outline it still sees. The flat check
decides the face of a standing plate whose outline shows it (a notch), from whichever face the
fit started (docs/bench/standing-parts.md: the generated parts' outlines do not show it)."""
from __future__ import annotations

import numpy as np
import pytest
from side_scene import SIDE, side_scene

from tlessbot_ros.core.common import (
    depth_to_points,
    make_transform,
    plane_of_frame,
    rotation_about_axis,
    rotation_angle_deg,
)
from tlessbot_ros.core.pose import PoseParams, Refiner, build_database
from tlessbot_ros.core.pose.flat import FlatCheck, ViewEvidence
from tlessbot_ros.core.pose.flat_turns import outline_half_turns

THICK = 0.004
STANDING = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi / 2), [0.0, 0.0, 0.0])


def _boxes(*boxes):
    """One mesh of axis-aligned boxes ((x0, y0, z0), (x1, y1, z1)) in metres."""
    trimesh = pytest.importorskip('trimesh')
    meshes = [trimesh.creation.box(extents=np.subtract(hi, lo), transform=make_transform(
        np.eye(3), (np.asarray(lo) + np.asarray(hi)) / 2)) for lo, hi in boxes]
    mesh = trimesh.util.concatenate(meshes)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.fixture(scope='module')
def notched_plate():
    """A plate 80 x 50 x 4 mm with a 15 mm notch at one corner, its faces down and standing on
    its long edge as stable poses."""
    v, f = _boxes(((0, 0, 0), (0.08, 0.035, THICK)), ((0, 0.035, 0), (0.065, 0.05, THICK)))
    face_down = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi), [0, 0, THICK])
    poses = [(np.eye(4), 0.45), (face_down, 0.45), (STANDING, 0.1)]
    db = build_database([(1, v, f, poses, None)], intrinsics=SIDE.intrinsics,
                        T_world_camera=SIDE.T_world_camera)
    return v, f, db[1]


def _face_seen_deg(T_world_object: np.ndarray) -> float:
    """The angle between the plate's face normal and the side camera's ray to the plate."""
    normal = T_world_object[:3, :3] @ np.array([0.0, 0.0, 1.0])
    ray = T_world_object[:3, 3] - SIDE.T_world_camera[:3, 3]
    return float(np.degrees(np.arccos(abs(normal @ ray) / np.linalg.norm(ray))))


@pytest.mark.parametrize('yaw_deg', [0, 60, 150])
def test_the_outline_decides_the_face_of_a_standing_plate(notched_plate, yaw_deg):
    v, f, obj = notched_plate
    T_world_object = make_transform(rotation_about_axis([0, 0, 1], np.radians(yaw_deg)),
                                    [-0.02, 0.0, 0.0]) @ STANDING
    assert _face_seen_deg(T_world_object) > 60   # the holes' sight angle is far exceeded
    rgb, depth, mask = side_scene(v, f, T_world_object, noise_m=0.0005, seed=yaw_deg,
                                  shaded=True)
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask)
    T_camera_world = np.linalg.inv(SIDE.T_world_camera)
    T_true = T_camera_world @ T_world_object
    evidence = [ViewEvidence(rgb, mask, SIDE.intrinsics, np.eye(4), depth,
                             plane_of_frame(SIDE.T_world_camera), None)]
    check = FlatCheck(Refiner(PoseParams()))
    # the fit 2 mm off in the table plane, on each of the four faces
    off = T_camera_world[:3, :3] @ np.array([0.002, 0.001, 0.0])
    for turn in [np.eye(4)] + outline_half_turns(obj.model_points.astype(np.float64)):
        start = T_true @ turn
        start[:3, 3] += off
        T, info = check.resolve(obj, start, points, SIDE.T_world_camera, evidence)
        final = start if T is None else T
        assert info['align_decided'] == 1.0, info
        assert rotation_angle_deg(final[:3, :3], T_true[:3, :3]) < 5.0, info
