"""The resting prior on a smoothed, stereo-like depth: neighbouring pixels share their noise,
which can show a plate lying flat a few degrees tilted. The prior judges the levelled pose
within the noise measured on the table around the part
(:func:`~tlessbot_ros.core.pose.flat_align.table_noise_m`), not within a per-pixel tolerance."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from side_scene import SIDE, holed_plate, side_scene

from tlessbot_ros.core.common import (
    depth_to_points,
    make_transform,
    plane_of_frame,
    resting_poses,
    rotation_about_axis,
    rotation_angle_deg,
)
from tlessbot_ros.core.pose import PoseParams, Refiner, build_database
from tlessbot_ros.core.pose.cloud import voxel_downsample
from tlessbot_ros.core.pose.flat_align import table_noise_m
from tlessbot_ros.core.pose.resting import RestingParams, settle

SHOWN_DEG = 5.0   # the tilt the shared noise shows
FIT_DEG = 7.0     # the free fit's


@pytest.fixture(scope='module')
def plate():
    """The 60 x 40 x 4 mm holed plate: (vertices m, faces, its templates, ``T_world_object``
    lying flat on the table)."""
    v, f = holed_plate()
    poses = resting_poses(v, f, float(np.linalg.norm(np.ptp(v, axis=0))))
    db = build_database([(1, v, f, poses, None)], intrinsics=SIDE.intrinsics,
                        T_world_camera=SIDE.T_world_camera)
    flat = next(T for T, _ in poses if abs(T[:3, :3][2, 2]) > 0.99)   # its 4 mm axis up
    T_true = make_transform(rotation_about_axis([0, 0, 1], np.radians(20.0)),
                            [0.0, 0.0, 0.0]) @ flat
    return v, f, db[1], T_true


def _shared_noise(shape: tuple[int, int], sigma_m: float, spread_px: float) -> np.ndarray:
    """A noise of about ``sigma_m`` that neighbouring pixels share over ``spread_px``."""
    field = cv2.GaussianBlur(np.random.default_rng(3).normal(0.0, 1.0, shape), (0, 0), spread_px)
    return field * (sigma_m / field.std())


def _tilted(obj, T_world_object: np.ndarray, angle_deg: float) -> np.ndarray:
    """``T_world_object`` tilted by ``angle_deg`` about its long axis through its centre (one
    long side down, the other as much up)."""
    R = rotation_about_axis(T_world_object[:3, 0], np.radians(angle_deg))
    centre = T_world_object[:3, :3] @ obj.model_points.mean(axis=0) + T_world_object[:3, 3]
    T = T_world_object.copy()
    T[:3, :3] = R @ T[:3, :3]
    T[:3, 3] = centre + R @ (T[:3, 3] - centre)
    return T


def _smoothed_view(plate, noise_m: float, shown_deg: float = SHOWN_DEG,
                   fit_deg: float = FIT_DEG):
    """The side camera's depth of the plate shown ``shown_deg`` tilted (as a smoothed depth's
    shared noise can show it) with ``noise_m`` of shared noise: (depth, part mask, the part's
    box, its ROI cloud as the fit sees it, and its free fit ``fit_deg`` tilted as
    T_camera_object)."""
    v, f, obj, T_true = plate
    T_shown = _tilted(obj, T_true, shown_deg)
    _, depth, mask = side_scene(v, f, T_shown, noise_m=0.0)
    depth = np.where(depth > 0, depth + _shared_noise(depth.shape, noise_m, 4.0), 0)
    depth = depth.astype(np.float32)
    ys, xs = np.nonzero(mask)
    box = (int(xs.min()), int(ys.min()), int(np.ptp(xs)) + 1, int(np.ptp(ys)) + 1)
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask)
    scene_c = voxel_downsample(points, obj.voxel_size_m)[0]
    T_fit = np.linalg.inv(SIDE.T_world_camera) @ _tilted(obj, T_true, fit_deg)
    return depth, mask, box, scene_c, T_fit


def test_the_table_s_shared_noise_is_measured_around_the_part(plate):
    depth, mask, box, _, _ = _smoothed_view(plate, 0.0015)
    plane = plane_of_frame(SIDE.T_world_camera)
    shared = table_noise_m(depth, SIDE.intrinsics, box, plane, mask)
    assert 0.0008 < shared < 0.003
    rng = np.random.default_rng(5)   # a per-pixel noise of 1.5 mm mostly averages out
    clean, _, _, _, _ = _smoothed_view(plate, 1e-9)
    per_pixel = (clean + rng.normal(0, 0.0015, clean.shape) * (clean > 0)).astype(np.float32)
    assert table_noise_m(per_pixel, SIDE.intrinsics, box, plane, mask) < 0.0004
    nothing = np.zeros_like(depth)   # no depth, no measure
    assert table_noise_m(nothing, SIDE.intrinsics, box, plane, mask) == 0.0


def test_a_plate_the_smoothed_depth_shows_tilted_is_levelled(plate):
    v, f, obj, T_true = plate
    depth, mask, box, scene_c, T_fit = _smoothed_view(plate, 0.0015)
    noise = table_noise_m(depth, SIDE.intrinsics, box, plane_of_frame(SIDE.T_world_camera),
                          mask)
    refiner = Refiner(PoseParams())
    # within a per-pixel tolerance (main's), the tilted fit explains more of the depth
    T, info = settle(refiner, obj, T_fit, scene_c, SIDE.T_world_camera, RestingParams())
    assert info['rest_tilt_deg'] == pytest.approx(FIT_DEG, abs=0.5) and T is None
    T, info = settle(refiner, obj, T_fit, scene_c, SIDE.T_world_camera, RestingParams(),
                     noise_m=noise)
    assert T is not None and info['rest_levelled'] == 1.0
    assert info['rest_tolerance_m'] > RestingParams().tolerance_m
    T_cw = np.linalg.inv(SIDE.T_world_camera)
    world_down = (SIDE.T_world_camera[:3, :3] @ T[:3, :3]).T @ np.array([0, 0, -1.0])
    true_down = T_true[:3, :3].T @ np.array([0, 0, -1.0])
    assert np.degrees(np.arccos(np.clip(world_down @ true_down, -1, 1))) < 0.5   # level
    assert rotation_angle_deg(T[:3, :3], (T_cw @ T_true)[:3, :3]) < 3.0
    # noise_ratio 0 is main's per-pixel tolerance
    T, _ = settle(refiner, obj, T_fit, scene_c, SIDE.T_world_camera,
                  RestingParams(noise_ratio=0.0), noise_m=noise)
    assert T is None


def test_a_negative_noise_ratio_is_refused():
    with pytest.raises(ValueError):
        RestingParams(noise_ratio=-1.0)


@pytest.mark.parametrize('yaw_deg, shift_m', [(4.0, 0.0), (-3.0, 0.0015)])
def test_a_levelled_plate_turned_off_is_turned_back_on_the_image_s_edges(plate, yaw_deg, shift_m):
    from tlessbot_ros.core.pose.flat import ViewEvidence
    from tlessbot_ros.core.pose.flat_turns import mesh_scene
    from tlessbot_ros.core.pose.rest_edges import refine_on_edges

    v, f, obj, T_true = plate
    rgb, depth, mask = side_scene(v, f, T_true, noise_m=0.0)
    centre = T_true[:3, :3] @ obj.model_points.mean(axis=0) + T_true[:3, 3]
    off = make_transform(rotation_about_axis([0, 0, 1], np.radians(yaw_deg)), [0, 0, 0])
    off[:3, 3] = centre - off[:3, :3] @ centre + [shift_m, 0.0, 0.0]
    T_cw = np.linalg.inv(SIDE.T_world_camera)
    evidence = [ViewEvidence(rgb, mask, SIDE.intrinsics, np.eye(4))]
    T, info = refine_on_edges(mesh_scene(obj), T_cw @ off @ T_true, SIDE.T_world_camera,
                              obj.model_points.astype(np.float64), evidence, max_yaw_deg=6.0,
                              max_shift_m=0.003, cap_px=3.0, jump_m=0.002, crease_deg=30.0)
    assert rotation_angle_deg(T[:3, :3], (T_cw @ T_true)[:3, :3]) < 1.0
    assert np.linalg.norm(T[:3, 3] - (T_cw @ T_true)[:3, 3]) < 0.001
    assert info['edge_after_px'] < info['edge_before_px']
    world = SIDE.T_world_camera @ T   # turned about the vertical only: still level, on the table
    assert (world[:3, :3] @ T_true[:3, :3].T)[2, 2] == pytest.approx(1.0, abs=1e-9)
    assert world[2, 3] == pytest.approx(T_true[2, 3], abs=1e-9)


def test_no_colour_no_refinement(plate):
    from tlessbot_ros.core.pose.flat import ViewEvidence
    from tlessbot_ros.core.pose.flat_turns import mesh_scene
    from tlessbot_ros.core.pose.rest_edges import refine_on_edges

    v, f, obj, T_true = plate
    _, _, mask = side_scene(v, f, T_true, noise_m=0.0)
    T_fit = np.linalg.inv(SIDE.T_world_camera) @ T_true
    T, info = refine_on_edges(mesh_scene(obj), T_fit, SIDE.T_world_camera,
                              obj.model_points.astype(np.float64),
                              [ViewEvidence(None, mask, SIDE.intrinsics, np.eye(4))],
                              max_yaw_deg=6.0, max_shift_m=0.003, cap_px=3.0, jump_m=0.002,
                              crease_deg=30.0)
    assert np.array_equal(T, T_fit) and info['edge_yaw_deg'] == 0.0


def test_a_part_too_small_in_the_image_to_show_a_turn_is_not_refined(plate):
    from tlessbot_ros.core.pose.flat import ViewEvidence
    from tlessbot_ros.core.pose.flat_turns import mesh_scene
    from tlessbot_ros.core.pose.rest_edges import refine_on_edges

    v, f, obj, T_true = plate
    rgb, _, mask = side_scene(v, f, T_true, noise_m=0.0)
    centre = T_true[:3, :3] @ obj.model_points.mean(axis=0) + T_true[:3, 3]
    off = make_transform(rotation_about_axis([0, 0, 1], np.radians(4.0)), [0, 0, 0])
    off[:3, 3] = centre - off[:3, :3] @ centre
    T_cw = np.linalg.inv(SIDE.T_world_camera)
    T_fit = T_cw @ off @ T_true
    # the plate's outline in the side view, as far as its corners reach from its centre
    K = SIDE.intrinsics.K
    corners = (T_fit[:3, :3] @ v.T).T + T_fit[:3, 3]
    middle = T_fit[:3, :3] @ obj.model_points.mean(axis=0) + T_fit[:3, 3]
    uv = corners[:, :2] / corners[:, 2:] * K[[0, 1], [0, 1]]
    farthest = np.max(np.linalg.norm(uv - middle[:2] / middle[2] * K[[0, 1], [0, 1]], axis=1))

    def refined(min_reach_px):
        return refine_on_edges(mesh_scene(obj), T_fit, SIDE.T_world_camera,
                               obj.model_points.astype(np.float64),
                               [ViewEvidence(rgb, mask, SIDE.intrinsics, np.eye(4))],
                               max_yaw_deg=6.0, max_shift_m=0.003, cap_px=3.0, jump_m=0.002,
                               crease_deg=30.0, min_reach_px=min_reach_px)
    T, info = refined(RestingParams().edge_min_reach_px)
    assert 0.5 * farthest < info['edge_reach_px'] <= farthest + 1.0
    assert rotation_angle_deg(T[:3, :3], (T_cw @ T_true)[:3, :3]) < 1.0
    T, info = refined(farthest + 2.0)   # the same plate, were it this small in the image
    assert np.array_equal(T, T_fit) and info['edge_yaw_deg'] == 0.0
    with pytest.raises(ValueError):
        RestingParams(edge_min_reach_px=-1.0)


def _settled(plate, shown_deg: float, fit_deg: float, params: RestingParams):
    """``settle`` on the side camera's smoothed depth (1.5 mm of shared noise) of the plate
    shown ``shown_deg`` tilted, from a free fit ``fit_deg`` tilted."""
    obj = plate[2]
    depth, mask, box, scene_c, T_fit = _smoothed_view(plate, 0.0015, shown_deg, fit_deg)
    noise = table_noise_m(depth, SIDE.intrinsics, box, plane_of_frame(SIDE.T_world_camera),
                          mask)
    return settle(Refiner(PoseParams()), obj, T_fit, scene_c, SIDE.T_world_camera, params,
                  noise_m=noise)


def test_a_plate_shown_7_deg_tilted_is_levelled_within_four_noise_widths(plate):
    # the shared noise shows the lying plate 7 deg tilted: within three times the noise
    # measured on the table the tilted fit still explains more of the part's own depth, within
    # four the levelled pose explains as much (a part's depth reads noisier than the table's)
    T, info = _settled(plate, 7.0, 8.0, RestingParams(noise_ratio=3.0))
    assert T is None and info['rest_best_fitness'] < info['rest_fitness'] - 0.02
    T, info = _settled(plate, 7.0, 8.0, RestingParams())
    assert T is not None and info['rest_levelled'] == 1.0
    # a plate the depth shows 10 deg tilted (about 7 mm across it) keeps its tilt
    T, info = _settled(plate, 10.0, 10.0, RestingParams())
    assert T is None and info['rest_tried'] > 0
