"""The table plane found in a depth image, its tracker, and the frames it gives
(core/common/table_plane.py)."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import (
    TablePlane,
    TablePlaneParams,
    TablePlaneTracker,
    above_table,
    align_frame_to_plane,
    choose_table_frame,
    default_rig,
    find_table_plane,
    invert_transform,
    make_transform,
    plane_difference,
    plane_of_frame,
    rotation_about_axis,
    table_frame_from_plane,
    table_with_box,
    transform_points,
)

RIG = default_rig()
SIDE, TOP = RIG['side'], RIG['top']


def _shifted(T_world_camera, offset_xy):
    """The camera seen from a world shifted so that a box at the origin stands at offset_xy."""
    return make_transform(np.eye(3), [-offset_xy[0], -offset_xy[1], 0.0]) @ T_world_camera


def table_scene(camera, *, seed=0, holes=0.2):
    """Depth of the table with three boxes (one 12 cm tall), D415-like noise (sigma 2.1 mm
    * z^2), a share ``holes`` of random NaN pixels and a zeroed block: (depth_m, true plane)."""
    depths = []
    for offset, size in (((0.0, 0.0), (0.12, 0.08, 0.12)), ((0.12, 0.05), (0.06, 0.05, 0.04)),
                         ((-0.1, -0.06), (0.05, 0.09, 0.03))):
        _, depth, _ = table_with_box(camera.intrinsics, _shifted(camera.T_world_camera, offset),
                                     box_size_m=size)
        depths.append(np.where(depth > 0, depth, np.inf))
    depth = np.min(depths, axis=0)
    rng = np.random.default_rng(seed)
    depth = depth + rng.normal(0.0, 1.0, depth.shape) * 0.0021 * depth ** 2
    depth[rng.random(depth.shape) < holes] = np.nan
    depth[100:180, 200:330] = 0.0
    return depth.astype(np.float32), plane_of_frame(camera.T_world_camera)


def _angle_deg(a, b):
    return float(np.degrees(np.arccos(np.clip(np.dot(a[:3], b[:3]), -1.0, 1.0))))


@pytest.mark.parametrize('camera', [SIDE, TOP], ids=['side', 'top'])
def test_the_noise_measured_on_the_table_sets_what_stands_clear_of_it(camera):
    depth, _ = table_scene(camera)
    table = find_table_plane(depth, camera.intrinsics.K)
    assert table is not None and table.noise_at_1m_m == pytest.approx(0.0021, rel=0.25)
    frame = choose_table_frame(None, table, mode='observed', max_angle_deg=10.0,
                               max_offset_m=0.05)
    T_camera_world = invert_transform(frame.T_world_camera)
    heights = np.array([0.0005, 0.0015, 0.0038, 0.010])
    points = transform_points(T_camera_world, np.c_[np.zeros((4, 2)), heights])
    fixed = transform_points(frame.T_world_camera, above_table(points, frame, 0.004))[:, 2]
    np.testing.assert_allclose(fixed, [0.010], atol=1e-6)
    kept = transform_points(frame.T_world_camera,
                            above_table(points, frame, 0.004, TablePlaneParams()))[:, 2]
    band = 3.0 * table.noise_at_1m_m * points[0, 2] ** 2   # the plane fit's inlier distance
    np.testing.assert_allclose(kept, heights[heights > min(max(band, 0.002), 0.004)],
                               atol=1e-6)
    # near (side, 0.64 m: 3 sigma 2.6 mm) a point 3.8 mm high stands clear of the table; far
    # (top, 1.1 m: 7.6 mm) the noise reaches above the fixed 4 mm, which stays the ceiling
    assert len(kept) == (2 if camera is SIDE else 1)


@pytest.mark.parametrize('camera', [SIDE, TOP], ids=['side', 'top'])
def test_the_table_is_found_under_parts_noise_and_holes(camera):
    depth, truth = table_scene(camera)
    table = find_table_plane(depth, camera.intrinsics.K)
    assert table is not None
    assert _angle_deg(table.plane, truth) < 0.1
    assert abs(table.camera_height_m - truth[3]) < 0.001
    assert table.plane[3] > 0 and np.dot(table.normal, table.centroid) < 0   # faces the camera
    assert 0.6 < table.inlier_share < 1.0      # the boxes are not on it
    # the same depth gives the same plane (seeded)
    np.testing.assert_array_equal(find_table_plane(depth, camera.intrinsics.K).plane,
                                  table.plane)


def test_no_table_without_valid_depth():
    K = SIDE.intrinsics.K
    for depth in (np.full((480, 640), np.nan, np.float32), np.zeros((480, 640), np.float32),
                  np.full((2, 2), 0.5, np.float32), np.full((480, 640), -1.0, np.float32)):
        assert find_table_plane(depth, K) is None
    # a cloud of random points holds no plane with 15 % of them
    noise = np.random.default_rng(1).uniform(0.3, 1.5, (480, 640)).astype(np.float32)
    assert find_table_plane(noise, K) is None
    with pytest.raises(ValueError, match='2-D'):
        find_table_plane(np.zeros((4, 4, 3)), K)
    with pytest.raises(ValueError, match='3x3'):
        find_table_plane(np.zeros((4, 4)), np.eye(2))


def test_a_wall_larger_than_the_table_loses_to_the_rigs_table():
    # A wall standing across the work area, 5 cm in front of its centre, facing the side camera,
    # fills most of its image: the largest plane. The rig's plane says which is the table.
    camera = SIDE
    _, table_depth, _ = table_with_box(camera.intrinsics, camera.T_world_camera)
    wall_world = make_transform(rotation_about_axis([1.0, 0, 0], np.pi / 2), [0, -0.05, 0])
    _, wall_depth, _ = table_with_box(camera.intrinsics,
                                      invert_transform(wall_world) @ camera.T_world_camera)
    depth = np.where((wall_depth > 0) & ((wall_depth < table_depth) | (table_depth == 0)),
                     wall_depth, table_depth).astype(np.float32)
    truth = plane_of_frame(camera.T_world_camera)
    largest = find_table_plane(depth, camera.intrinsics.K)
    assert largest is not None and _angle_deg(largest.plane, truth) > 45
    table = find_table_plane(depth, camera.intrinsics.K, prior=truth)
    assert table is not None and _angle_deg(table.plane, truth) < 0.1
    # a rig 5 degrees off still picks the table, and the plane is the depth's, not the rig's
    tilted = make_transform(rotation_about_axis([1.0, 0, 0], np.radians(5)), [0, 0, 0.01])
    prior = plane_of_frame(tilted @ camera.T_world_camera)
    table = find_table_plane(depth, camera.intrinsics.K, prior=prior)
    assert table is not None and _angle_deg(table.plane, truth) < 0.1


def _plane(normal, height):
    """A plane seen at the foot of the camera centre."""
    normal = np.asarray(normal, float) / np.linalg.norm(normal)
    return TablePlane(np.append(normal, height), 0.9, 4800, -height * normal)


def test_the_tracker_smooths_and_resets_on_a_jump():
    params = TablePlaneParams(smoothing=0.5, reset_angle_deg=1.0, hold_frames=2)
    tracker = TablePlaneTracker(params)
    rng = np.random.default_rng(0)
    truth = np.array([0.0, -0.94, -0.34])
    truth /= np.linalg.norm(truth)
    raw, smoothed = [], []
    for _ in range(40):
        observed = _plane(truth + rng.normal(0, 0.002, 3), 0.6 + rng.normal(0, 0.001))
        tracked = tracker.update(observed)
        raw.append(_angle_deg(observed.plane, truth))
        smoothed.append(_angle_deg(tracked.plane, truth))
    assert tracker.resets == 0
    assert np.mean(smoothed[10:]) < 0.75 * np.mean(raw[10:])
    # the camera was moved: 5 degrees of tilt are taken at once, not blended in
    moved = rotation_about_axis([1.0, 0, 0], np.radians(5)) @ truth
    tracked = tracker.update(_plane(moved, 0.6))
    np.testing.assert_allclose(tracked.plane[:3], moved)
    assert tracker.resets == 1
    # so is a 2 cm shift
    assert tracker.update(_plane(moved, 0.62)).camera_height_m == pytest.approx(0.62)
    assert tracker.resets == 2
    # frames without a table keep the last plane for hold_frames frames
    assert tracker.update(None) is not None and tracker.update(None) is not None
    assert tracker.update(None) is None


def test_frames_from_a_plane():
    truth = plane_of_frame(SIDE.T_world_camera)
    points_c = np.random.default_rng(0).uniform(-0.2, 0.2, (20, 3)) + [0, 0, 0.6]
    heights = transform_points(SIDE.T_world_camera, points_c)[:, 2]
    # without a rig: yaw and origin are free, heights above the table are not
    T = table_frame_from_plane(-truth)          # either orientation of the plane
    np.testing.assert_allclose(transform_points(T, points_c)[:, 2], heights, atol=1e-9)
    # a rig 3 degrees and 1 cm off, aligned to the plane: the heights are right again and the
    # rig's yaw is kept
    error = make_transform(rotation_about_axis([0.3, 1.0, 0], np.radians(3)), [0.01, 0, 0.01])
    wrong = error @ SIDE.T_world_camera
    seen_at = points_c[0] - (truth[:3] @ points_c[0] + truth[3]) * truth[:3]   # on the table
    table = TablePlane(truth, 0.9, 100, seen_at)
    angle, offset = plane_difference(wrong, table)
    assert angle == pytest.approx(3.0, abs=1e-6)
    assert offset == pytest.approx(transform_points(wrong, seen_at[None])[0, 2], abs=1e-9)
    assert abs(offset) > 0.005
    aligned = align_frame_to_plane(wrong, truth)
    np.testing.assert_allclose(transform_points(aligned, points_c)[:, 2], heights, atol=1e-9)
    x_rig, x_aligned = wrong[:3, :3].T[0], aligned[:3, :3].T[0]
    assert _angle_deg(x_rig, x_aligned) < 3.0 + 1e-6
    assert plane_difference(aligned, table)[0] == pytest.approx(0.0, abs=1e-4)


def test_the_frame_chosen_in_each_mode():
    T_rig = SIDE.T_world_camera
    agreeing = TablePlane(plane_of_frame(T_rig), 0.9, 100, np.array([0.0, 0.1, 0.6]))
    tilt = make_transform(rotation_about_axis([1.0, 0, 0], np.radians(2)), np.zeros(3))
    disagreeing = TablePlane(plane_of_frame(tilt @ T_rig), 0.9, 100, agreeing.centroid)

    def choose(T, observed, mode):
        return choose_table_frame(T, observed, mode=mode, max_angle_deg=1.0, max_offset_m=0.005)

    assert choose(T_rig, agreeing, 'auto').source == 'rig'
    assert choose(T_rig, agreeing, 'auto').T_world_camera is T_rig
    frame = choose(T_rig, disagreeing, 'auto')
    assert frame.source == 'observed' and frame.rig_angle_deg == pytest.approx(2.0)
    np.testing.assert_allclose(plane_of_frame(frame.T_world_camera), disagreeing.plane,
                               atol=1e-12)
    assert choose(T_rig, disagreeing, 'rig').T_world_camera is T_rig
    assert choose(T_rig, agreeing, 'observed').source == 'observed'
    assert choose(None, agreeing, 'auto').source == 'observed'
    assert choose(None, agreeing, 'rig') .source == 'none'
    assert choose(None, None, 'observed').T_world_camera is None
    assert choose(T_rig, None, 'observed').source == 'rig'     # no table seen: the rig
    with pytest.raises(ValueError, match='mode'):
        choose(T_rig, agreeing, 'yaml')
