"""The rig from the scene (core/calibrate): in-plane geometry, part points above the table,
the estimator on synthetic two-view scenes with a known rig, and the localiser's refiner."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tlessbot_ros.core.calibrate import (
    SceneCalibrationParams,
    SceneCalibrator,
    observe_view,
    rig_differences,
    rig_errors,
)
from tlessbot_ros.core.calibrate.inplane import (
    inplane_parameters,
    inplane_transform,
    level_camera_on_plane,
    procrustes_2d,
)
from tlessbot_ros.core.calibrate.refinement import RigRefinementParams, RigRefiner
from tlessbot_ros.core.common import (
    CameraMount,
    Rig,
    d415_intrinsics,
    default_rig,
    invert_transform,
    look_at,
    look_at_params,
    plane_of_frame,
    rotation_about_axis,
    table_with_box,
    transform_points,
)

# 320x240 keeps the ray casting cheap; the strides follow the focal length
PRIOR = Rig(cameras={name: CameraMount(name, d415_intrinsics(320, 240), mount.T_world_camera)
                     for name, mount in default_rig().cameras.items()})


def moved(rig: Rig, name: str, *, shift=(0.0, 0.0, 0.0), yaw_deg=0.0, tilt_deg=0.0) -> Rig:
    """``rig`` with camera ``name`` turned about the vertical and about its own x axis (both
    through its centre) and shifted, as a bump of its bracket would."""
    T = rig[name].T_world_camera.copy()
    T[:3, :3] = rotation_about_axis([0, 0, 1], np.radians(yaw_deg)) @ T[:3, :3] @ \
        rotation_about_axis([1, 0, 0], np.radians(tilt_deg))
    T[:3, 3] += shift
    return Rig(cameras={**rig.cameras, name: CameraMount(name, rig[name].intrinsics, T)})


# the rig of the scenes: both cameras bumped (the gate allows 5 cm and 15 deg each)
TRUTH = moved(moved(PRIOR, 'top', shift=(0.03, -0.02, 0.02), yaw_deg=12.0, tilt_deg=3.0),
              'side', shift=(0.04, -0.03, -0.02), yaw_deg=-10.0, tilt_deg=5.0)


def render(rig: Rig, boxes, *, seed=0, noise=True) -> dict[str, np.ndarray]:
    """Per camera, (H, W) float32 depth of the table with ``boxes`` ((x, y, yaw), (sx, sy,
    sz)) standing on it, D415-like noise (2.1 mm at 1 m, growing with z squared)."""
    rng = np.random.default_rng(seed)
    out = {}
    for name, mount in rig.cameras.items():
        depths = []
        # the table alone: a box far outside the view
        for (x, y, yaw), size in [((50.0, 0.0, 0.0), (0.01, 0.01, 0.01)), *boxes]:
            T_box_camera = invert_transform(inplane_transform(yaw, x, y)) @ mount.T_world_camera
            _, depth, _ = table_with_box(mount.intrinsics, T_box_camera, box_size_m=size)
            depths.append(np.where(depth > 0, depth, np.inf))
        depth = np.min(depths, axis=0)
        depth = np.where(np.isfinite(depth), depth, 0.0)
        if noise:
            depth = depth + rng.normal(0.0, 1.0, depth.shape) * 0.0021 * depth ** 2
        out[name] = depth.astype(np.float32)
    return out


def random_boxes(rng: np.random.Generator, count: int):
    return [((rng.uniform(-0.12, 0.12), rng.uniform(-0.1, 0.1), rng.uniform(0, np.pi)),
             tuple(rng.uniform([0.02, 0.02, 0.015], [0.07, 0.06, 0.06]))) for _ in range(count)]


def scenes(rig: Rig, frames: int, *, seed=0, parts=(1, 6)):
    rng = np.random.default_rng(seed)
    return [render(rig, random_boxes(rng, int(rng.integers(parts[0], parts[1] + 1))),
                   seed=seed * 100 + k) for k in range(frames)]


@pytest.fixture(scope='module')
def bumped_frames():
    return scenes(TRUTH, 6, seed=3)


# ------------------------------------------------------------------------------ in-plane
def test_procrustes_2d_recovers_a_known_turn_and_shift():
    rng = np.random.default_rng(0)
    source = rng.uniform(-0.2, 0.2, (20, 3))
    G = inplane_transform(np.radians(13.0), 0.04, -0.03)
    target = transform_points(G, source)
    fitted = procrustes_2d(source, target)
    np.testing.assert_allclose(fitted, G, atol=1e-12)
    assert np.allclose(inplane_parameters(fitted), (np.radians(13.0), 0.04, -0.03))
    # one pair: a shift alone
    one = procrustes_2d(source[:1], target[:1])
    assert inplane_parameters(one)[0] == 0.0
    np.testing.assert_allclose(transform_points(one, source[:1]), target[:1], atol=1e-12)
    with pytest.raises(ValueError, match='same'):
        procrustes_2d(source[:3], target[:2])


def test_levelling_keeps_the_camera_in_place_and_takes_tilt_and_height_from_the_plane():
    truth = moved(PRIOR, 'side', tilt_deg=6.0, shift=(0.0, 0.0, 0.03))['side'].T_world_camera
    prior = PRIOR['side'].T_world_camera
    levelled = level_camera_on_plane(prior, plane_of_frame(truth))
    # the table seen from the levelled camera is the true one
    np.testing.assert_allclose(plane_of_frame(levelled), plane_of_frame(truth), atol=1e-12)
    np.testing.assert_allclose(levelled[:2, 3], prior[:2, 3])        # x, y kept
    assert levelled[2, 3] == pytest.approx(truth[2, 3])
    # an already level camera is left as it is
    np.testing.assert_allclose(level_camera_on_plane(prior, plane_of_frame(prior)), prior,
                               atol=1e-12)


def test_look_at_params_give_the_pose_back():
    for mount in TRUTH.cameras.values():
        np.testing.assert_allclose(look_at(*look_at_params(mount.T_world_camera)),
                                   mount.T_world_camera, atol=1e-12)


# ------------------------------------------------------------------------------ observing
def test_part_points_are_grouped_per_part_and_an_empty_table_has_none():
    boxes = [((-0.08, 0.0, 0.3), (0.05, 0.04, 0.03)), ((0.08, 0.03, 1.0), (0.04, 0.04, 0.05))]
    depth = render(PRIOR, boxes)
    empty = render(PRIOR, [])
    for name, mount in PRIOR.cameras.items():
        plane = plane_of_frame(mount.T_world_camera)
        seen = observe_view(depth[name], mount.intrinsics.K, plane, stride_px=2)
        assert seen.blobs == 2 and not seen.cut.any()
        heights = transform_points(mount.T_world_camera, seen.points)[:, 2]
        assert heights.min() > 0.005 and heights.max() < 0.06   # boxes 3 and 5 cm tall
        assert observe_view(empty[name], mount.intrinsics.K, plane, stride_px=2).blobs == 0


# ------------------------------------------------------------------------------ estimating
def test_a_bumped_rig_is_recovered_from_parts_seen_by_both_views(bumped_frames):
    calibrator = SceneCalibrator(PRIOR)
    for depth in bumped_frames:
        calibrator.add_frame(depth)
    estimate = calibrator.solve()
    assert estimate.confident, estimate.summary()
    errors = rig_errors(TRUTH, estimate.rig)
    assert errors.relative.angle_deg < 0.5 and errors.relative.offset_m < 0.005, errors
    for name in ('top', 'side'):
        assert abs(errors.height_m[name]) < 0.001 and errors.tilt_deg[name] < 0.1, errors
    before = rig_errors(TRUTH, PRIOR)
    assert before.relative.angle_deg > 20.0             # the prior was far off
    # what the estimate says of the prior: the same as the truth says
    assert estimate.differences['top_side'].angle_deg == pytest.approx(
        rig_differences(PRIOR, TRUTH)['top_side'].angle_deg, abs=0.5)
    assert estimate.overlap > 0.8 > estimate.prior_overlap


def test_the_gauge_is_the_prior_top_cameras_place_and_heading(bumped_frames):
    calibrator = SceneCalibrator(PRIOR)
    for depth in bumped_frames[:3]:
        calibrator.add_frame(depth)
    top = calibrator.solve().rig['top'].T_world_camera
    prior = PRIOR['top'].T_world_camera
    np.testing.assert_allclose(top[:2, 3], prior[:2, 3])
    # its heading: the image's up direction keeps its compass direction
    heading = np.arctan2(-top[1, 1], -top[0, 1]), np.arctan2(-prior[1, 1], -prior[0, 1])
    assert abs(np.degrees(heading[0] - heading[1])) < 1.0


def test_a_right_prior_is_confirmed():
    calibrator = SceneCalibrator(PRIOR)
    for depth in scenes(PRIOR, 4, seed=5):
        calibrator.add_frame(depth)
    estimate = calibrator.solve()
    assert estimate.confident
    assert all(d.angle_deg < 0.3 and d.offset_m < 0.003 for d in estimate.differences.values())


def test_no_parts_give_tilt_and_height_only_and_one_view_parts_are_ignored():
    truth = moved(PRIOR, 'side', tilt_deg=4.0, yaw_deg=5.0, shift=(0.0, 0.02, 0.01))
    calibrator = SceneCalibrator(PRIOR)
    for k in range(3):
        calibrator.add_frame(render(truth, [], seed=k))
    # a part far off to the right: in the top view only
    frame = calibrator.add_frame(render(truth, [((0.45, 0.0, 0.0), (0.05, 0.05, 0.04))]))
    assert frame.views['top'].blobs == 1 and frame.views['side'].blobs == 0
    estimate = calibrator.solve()
    assert not estimate.in_plane_solved and not estimate.confident
    errors = rig_errors(truth, estimate.rig)
    for name in ('top', 'side'):
        assert abs(errors.height_m[name]) < 0.001 and errors.tilt_deg[name] < 0.1, errors
    assert estimate.rig is not estimate.prior and estimate.planes == 4


def test_a_camera_that_moves_starts_the_estimate_again():
    params = dataclasses.replace(SceneCalibrationParams(), min_frames=2)
    calibrator = SceneCalibrator(PRIOR, params=params)
    for depth in scenes(PRIOR, 2, seed=7):
        calibrator.add_frame(depth)
    bumped = moved(PRIOR, 'side', tilt_deg=4.0, yaw_deg=-6.0, shift=(0.02, 0.0, 0.0))
    for depth in scenes(bumped, 3, seed=8):
        calibrator.add_frame(depth)
    assert calibrator.resets == 1
    estimate = calibrator.solve()
    errors = rig_errors(bumped, estimate.rig)
    assert errors.relative.angle_deg < 0.5 and errors.relative.offset_m < 0.005, errors


def test_bad_settings_are_refused_with_the_field_named():
    with pytest.raises(ValueError, match='icp_distance_m'):
        SceneCalibrationParams(icp_distance_m=0.05)
    with pytest.raises(ValueError, match='mode'):
        RigRefinementParams(mode='always')


# ------------------------------------------------------------------------------ refiner
@pytest.mark.parametrize('mode', ['use', 'report'])
def test_the_refiner_switches_to_the_observed_rig_only_in_use_mode(mode, bumped_frames):
    refiner = RigRefiner(PRIOR, RigRefinementParams(mode=mode))
    changes = [refiner.observe(depth) for depth in bumped_frames]
    status = refiner.status()
    assert refiner.estimate.confident and status.warn
    assert 'top_side' in status.message and status.values['rig_state'] == 'confident'
    if mode == 'use':
        assert refiner.in_use == 'observed' and any(changes)
        assert rig_errors(TRUTH, refiner.rig).relative.offset_m < 0.005
    else:
        assert refiner.in_use == 'config' and refiner.rig is PRIOR and not any(changes)
    assert refiner.cost_ms > 0 and refiner.solves >= 1


def test_the_refiner_keeps_a_right_rig():
    refiner = RigRefiner(PRIOR)
    for depth in scenes(PRIOR, 4, seed=5):
        refiner.observe(depth)
    assert refiner.estimate.confident and refiner.in_use == 'config'
    assert refiner.rig is PRIOR and not refiner.status().warn


def test_one_frame_with_parts_gives_a_provisional_rig_but_never_replaces_a_right_one(
        bumped_frames):
    refiner = RigRefiner(PRIOR)
    assert refiner.observe(bumped_frames[0])
    assert refiner.in_use == 'observed' and refiner.status().values['rig_state'] == 'provisional'
    errors = rig_errors(TRUTH, refiner.rig)
    assert errors.relative.angle_deg < 1.0 and errors.relative.offset_m < 0.01, errors
    right = RigRefiner(PRIOR)
    right.observe(scenes(PRIOR, 1, seed=5)[0])
    assert right.in_use == 'config' and right.rig is PRIOR


def test_once_confident_the_refiner_takes_parts_from_every_fifth_frame_only(bumped_frames):
    refiner = RigRefiner(PRIOR)
    for depth in bumped_frames[:3]:
        refiner.observe(depth)
    assert refiner.estimate.confident
    kept, planes = len(refiner.calibrator.frames), len(refiner.calibrator.planes['side'])
    for depth in bumped_frames * 2:   # 12 more frames
        refiner.observe(depth)
    assert len(refiner.calibrator.frames) - kept in (2, 3)
    assert len(refiner.calibrator.planes['side']) - planes == 12
