"""The resting-pose prior: a fit on the table that is tilted out of every stable pose of its
part is levelled onto the nearest one when that fits the depth as well; a part that leans (its
depth shows it tilted) or lies on something (above the table) keeps its fit."""
from __future__ import annotations

import numpy as np
import pytest
from side_scene import SIDE, side_scene

from tlessbot_ros.core.common import (
    depth_to_points,
    make_transform,
    resting_poses,
    rotation_about_axis,
    rotation_angle_deg,
)
from tlessbot_ros.core.pose import PoseParams, Refiner, build_database
from tlessbot_ros.core.pose.cloud import voxel_downsample
from tlessbot_ros.core.pose.derived import derived_arrays, restore_derived
from tlessbot_ros.core.pose.resting import (
    RestingParams,
    levelled,
    settle,
    stable_directions,
    stable_offsets,
)
from tlessbot_ros.tools.support import part_generator as gen


@pytest.fixture(scope='module')
def block():
    """The generator's drilled block: (vertices m, faces), its most probable resting pose
    ``T_table_object`` and its templates."""
    sdf, (low, high) = gen.part_shapes()['block_drilled']
    v, f = gen.mesh_part(sdf, low, high, spacing_mm=0.8)
    v = v / 1000.0
    poses = resting_poses(v, f, float(np.linalg.norm(np.ptp(v, axis=0))))
    db = build_database([(1, v, f, poses, None)], intrinsics=SIDE.intrinsics,
                        T_world_camera=SIDE.T_world_camera)
    return v, f, poses[0][0], db[1]


def _scene(v, f, T_world_object, voxel):
    """The part's ROI cloud in the side camera (0.5 mm noise), voxelised as the fit sees it."""
    _, depth, mask = side_scene(v, f, T_world_object, noise_m=0.0005)
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask)
    return voxel_downsample(points, voxel)[0]


def _tilted(T_world_object, angle_deg, centre_o):
    """``T_world_object`` tilted by ``angle_deg`` about a horizontal axis through the part's
    ``centre_o``."""
    R = rotation_about_axis([1.0, 0.5, 0.0], np.radians(angle_deg))
    centre = T_world_object[:3, :3] @ centre_o + T_world_object[:3, 3]
    T = T_world_object.copy()
    T[:3, :3] = R @ T[:3, :3]
    T[:3, 3] = centre + R @ (T[:3, 3] - centre)
    return T


def _placed(T_table_object, xy=(0.01, -0.02), yaw_deg=30.0):
    return make_transform(rotation_about_axis([0, 0, 1], np.radians(yaw_deg)),
                          [xy[0], xy[1], 0.0]) @ T_table_object


def test_the_stable_directions_are_the_resting_poses_gravity(block):
    v, f, T_rest, obj = block
    table = stable_directions(obj)
    assert table is not None and len(table) >= 4
    assert np.isclose(table[:, 3].sum(), 1.0)
    assert np.allclose(np.linalg.norm(table[:, :3], axis=1), 1.0)
    angle, _ = stable_offsets(obj, _placed(T_rest)[:3, :3])
    assert angle.min() < 1e-6                      # resting: on a stable pose exactly
    angle, _ = stable_offsets(obj, _tilted(_placed(T_rest), 10.0, v.mean(axis=0))[:3, :3])
    assert angle.min() == pytest.approx(10.0, abs=0.5)


def test_levelled_puts_the_stable_face_down_and_on_the_table(block):
    v, _, T_rest, obj = block
    T = _tilted(_placed(T_rest), 10.0, v.mean(axis=0))
    angle, nearest = stable_offsets(obj, T[:3, :3])
    out = levelled(T, nearest[np.argmin(angle)][None], v, v.mean(axis=0))[0]
    assert rotation_angle_deg(out[:3, :3], _placed(T_rest)[:3, :3]) < 0.5   # yaw kept
    assert (v @ out[:3, :3].T + out[:3, 3])[:, 2].min() == pytest.approx(0.0, abs=1e-9)


def test_a_fit_ten_degrees_off_its_stable_pose_on_the_table_is_levelled(block):
    v, f, T_rest, obj = block
    T_true = _placed(T_rest)
    scene_c = _scene(v, f, T_true, obj.voxel_size_m)
    T_cw = np.linalg.inv(SIDE.T_world_camera)
    T_fit = T_cw @ _tilted(T_true, 10.0, obj.model_points.mean(axis=0))
    T, info = settle(Refiner(PoseParams()), obj, T_fit, scene_c, SIDE.T_world_camera,
                     RestingParams())
    assert info['rest_tilt_deg'] == pytest.approx(10.0, abs=0.5)
    assert abs(info['rest_contact_m']) < RestingParams().contact_m
    assert T is not None and info['rest_levelled'] == 1.0
    assert rotation_angle_deg(T[:3, :3], (T_cw @ T_true)[:3, :3]) < 2.0
    assert np.linalg.norm(T[:3, 3] - (T_cw @ T_true)[:3, 3]) < 0.002
    assert info['rest_best_fitness'] >= info['rest_fitness']


def test_a_leaning_part_keeps_its_fit(block):
    """Tilted 15 degrees with an edge on the table, as against a neighbour: its depth shows
    the tilt, and no stable pose fits it as well."""
    v, f, T_rest, obj = block
    T_lean = _tilted(_placed(T_rest), 15.0, v.mean(axis=0))
    T_lean[2, 3] -= (v @ T_lean[:3, :3].T + T_lean[:3, 3])[:, 2].min()   # edge on the table
    scene_c = _scene(v, f, T_lean, obj.voxel_size_m)
    T_fit = np.linalg.inv(SIDE.T_world_camera) @ T_lean
    T, info = settle(Refiner(PoseParams()), obj, T_fit, scene_c, SIDE.T_world_camera,
                     RestingParams())
    assert info['rest_tried'] >= 1                   # it was on the table, and tried
    assert T is None and info['rest_levelled'] == 0.0
    assert info['rest_best_fitness'] < info['rest_fitness'] - RestingParams().fitness_margin


def test_a_part_above_the_table_keeps_its_fit(block):
    """Lying on another part 1 cm up, tilted: not on the table, not tried."""
    v, f, T_rest, obj = block
    T_up = _tilted(_placed(T_rest), 10.0, v.mean(axis=0))
    T_up[2, 3] += 0.01 - (v @ T_up[:3, :3].T + T_up[:3, 3])[:, 2].min()
    scene_c = _scene(v, f, T_up, obj.voxel_size_m)
    T, info = settle(Refiner(PoseParams()), obj, np.linalg.inv(SIDE.T_world_camera) @ T_up,
                     scene_c, SIDE.T_world_camera, RestingParams())
    assert T is None and info['rest_tried'] == 0.0
    assert info['rest_contact_m'] == pytest.approx(0.01, abs=1e-6)


def test_the_stable_directions_travel_with_the_derived_cache(block):
    _, _, _, obj = block
    db = build_database([(1, obj.mesh_vertices, obj.mesh_faces,
                          [(obj.stable_poses[0], 1.0)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    arrays = derived_arrays(db, fingerprint='x')
    assert any('stable_downs' in k for k in arrays)
    fresh = build_database([(1, obj.mesh_vertices, obj.mesh_faces,
                             [(obj.stable_poses[0], 1.0)], None)],
                           intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    assert restore_derived(fresh, arrays, fingerprint='x')
    restored = fresh[1].derived_items()[('stable_downs',)]
    assert np.array_equal(restored, stable_directions(db[1]))


def test_resting_params_are_checked():
    with pytest.raises(ValueError):
        RestingParams(min_tilt_deg=40.0, max_tilt_deg=30.0)
    with pytest.raises(ValueError):
        RestingParams(contact_m=0.0)
