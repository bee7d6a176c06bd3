"""core.pose.fallback.without_clutter: with a table frame and fallback_table_band > 0 the fallback
drops the known table by height, not the plane a RANSAC search lands on; without a table
frame, or with fallback_table_band 0 (the default), the search as before."""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np

from tlessbot_ros.core.common import default_rig, make_transform, rotation_about_axis
from tlessbot_ros.core.pose import PoseParams
from tlessbot_ros.core.pose.fallback import without_clutter

SIDE = default_rig()['side']     # a camera tilted down at the table
PLATE_TOP_M = 0.004              # a thin plate: its top lies near the table's plane
PART = SimpleNamespace(diameter_m=0.094)
KNOWN = PoseParams(fallback_table_band=1.0)


def _grid(x0, x1, y0, y1, z, step):
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step))
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)


def _plate_on_table(T_world_camera, *, seed=1):
    """(N, 3) camera-frame ROI: the table around a 8 x 5 cm plate and the plate's top, with
    0.7 mm of depth noise; and (N,) bool: the point is the plate's."""
    table = _grid(-0.09, 0.09, -0.07, 0.07, 0.0, 0.004)
    table = table[(np.abs(table[:, 0]) > 0.045) | (np.abs(table[:, 1]) > 0.03)]
    plate = _grid(-0.04, 0.04, -0.025, 0.025, PLATE_TOP_M, 0.003)
    world = np.concatenate([table, plate])
    world[:, 2] += np.random.default_rng(seed).normal(0.0, 0.0007, len(world))
    T_camera_world = np.linalg.inv(T_world_camera)
    points = world @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
    return points, np.r_[np.zeros(len(table), bool), np.ones(len(plate), bool)]


def _kept(points, is_plate, kept):
    """How many of the plate's and of the table's points are in ``kept``."""
    rows = {tuple(p) for p in np.round(kept, 9)}
    inside = np.array([tuple(p) in rows for p in np.round(points, 9)])
    return int((inside & is_plate).sum()), int((inside & ~is_plate).sum())


def test_the_known_table_leaves_and_the_plate_stays():
    points, is_plate = _plate_on_table(SIDE.T_world_camera)
    plate, table = _kept(points, is_plate, without_clutter(points, PART, KNOWN,
                                                            SIDE.T_world_camera))
    assert table == 0 and plate >= 0.9 * is_plate.sum()
    # The plane search settles on a plane between the table and the plate's top: it keeps a
    # strip of table and takes part of the plate with it.
    searched = without_clutter(points, PART, PoseParams(fallback_table_band=0.0),
                               SIDE.T_world_camera)
    plate_s, table_s = _kept(points, is_plate, searched)
    assert table_s > 0 and plate_s < 0.8 * is_plate.sum()


def test_any_rig_and_no_table_frame():
    # The rule reads heights in the table frame: another camera pose, the same points kept.
    moved = make_transform(rotation_about_axis([0, 0, 1], np.radians(70.0)),
                           [0.05, -0.02, 0.0]) @ SIDE.T_world_camera
    tilted = make_transform(rotation_about_axis([1, 0, 0], np.radians(-25.0)),
                            [0.0, 0.0, 0.0]) @ moved
    for T in (SIDE.T_world_camera, tilted):
        points, is_plate = _plate_on_table(T)
        plate, table = _kept(points, is_plate, without_clutter(points, PART, KNOWN, T))
        assert table == 0 and plate >= 0.9 * is_plate.sum()
    # Without a table frame, or with the band off (the default), the search alone, as before.
    points, _ = _plate_on_table(SIDE.T_world_camera)
    searched = without_clutter(points, PART, PoseParams(), SIDE.T_world_camera)
    np.testing.assert_array_equal(without_clutter(points, PART, KNOWN), searched)
    # No plane to drop at all: nothing leaves.
    assert len(without_clutter(points, PART, replace(KNOWN, fallback_drop_planes=0),
                               SIDE.T_world_camera)) == len(points)


def test_a_part_seen_without_the_table_keeps_its_rim():
    # Only the plate's top and its lowest millimetres (no table around it): the points near
    # the table spread no wider than the part, so nothing leaves.
    points, is_plate = _plate_on_table(SIDE.T_world_camera)
    rim = np.random.default_rng(2).normal(0.0, 0.0007, (40, 3)) * [20.0, 20.0, 1.0] + \
        [0.0, 0.0, 0.001]
    T_camera_world = np.linalg.inv(SIDE.T_world_camera)
    part = np.concatenate([points[is_plate], rim @ T_camera_world[:3, :3].T
                           + T_camera_world[:3, 3]])
    assert len(without_clutter(part, PART, KNOWN, SIDE.T_world_camera)) == len(part)


def test_a_wall_beside_the_known_table_is_searched_as_a_second_plane():
    points, is_plate = _plate_on_table(SIDE.T_world_camera)
    y, z = np.meshgrid(np.arange(-0.07, 0.07, 0.003), np.arange(0.01, 0.1, 0.003))
    wall_w = np.stack([np.full(y.size, 0.07), y.ravel(), z.ravel()], axis=1)
    T_camera_world = np.linalg.inv(SIDE.T_world_camera)
    wall = wall_w @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
    scene = np.concatenate([points[is_plate], wall])
    # The known table is the first plane: with one plane the wall stays, with two it leaves.
    assert len(without_clutter(scene, PART, KNOWN, SIDE.T_world_camera)) == len(scene)
    two = without_clutter(scene, PART, replace(KNOWN, fallback_drop_planes=2),
                          SIDE.T_world_camera)
    assert len(two) == is_plate.sum()
