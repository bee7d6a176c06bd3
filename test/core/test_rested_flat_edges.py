"""A round flat part (a disc with four bolt holes) whose fit rests on its face already (level
within ``resting.min_tilt_deg``) but is turned a few degrees about its axis: only its holes
hold its yaw, and a smoothed depth does not show them, so the resting prior refines it on the
image's edges as it does a pose it levelled (``resting.edge_rested_round``; off, the fit stays
as it was). A plate, whose outline holds its yaw, is left as it rests. The same disc tilted
(levelled by the prior) or counted too thick to be flat (a flange) is searched over half its
period too (``resting.edge_round_levelled``, ``resting.edge_round_thick``)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from side_scene import (
    SIDE,
    holed_disc_database,
    holed_disc_mesh,
    holed_plate,
    side_scene,
    yaw_error_deg,
)

from tlessbot_ros.core.common import (
    depth_to_points,
    make_transform,
    resting_poses,
    rotation_about_axis,
    rotation_angle_deg,
)
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import build_database
from tlessbot_ros.core.pose.candidates import PoseCandidate
from tlessbot_ros.core.resting_check import check_resting_and_turns

TURN_DEG = 6.0   # the fit's yaw error: the holes 16 mm out move 1.7 mm, 1.6 px at 0.6 m


@pytest.fixture(scope='module')
def disc():
    """The 47 x 4.4 mm disc with four 3.8 mm holes (a quarter-turn period) lying on its face,
    and the 60 x 40 x 4 mm holed plate: each (its templates, its true ``T_world_object``)."""
    vertices, faces = holed_disc_mesh()
    db, T_world = holed_disc_database(vertices, faces)
    return db, vertices, faces, T_world


@pytest.fixture(scope='module')
def plate():
    v, f = holed_plate()
    poses = resting_poses(v, f, float(np.linalg.norm(np.ptp(v, axis=0))))
    db = build_database([(1, v, f, poses, None)], intrinsics=SIDE.intrinsics,
                        T_world_camera=SIDE.T_world_camera)
    flat = next(T for T, _ in poses if abs(T[:3, :3][2, 2]) > 0.99)   # its 4 mm axis up
    return db, v, f, make_transform(rotation_about_axis([0, 0, 1], np.radians(20.0)),
                                    [0.0, 0.0, 0.0]) @ flat


def _checked(part, fit: FitParams, turn_deg: float = TURN_DEG, tilt_deg: float = 0.0
             ) -> tuple[np.ndarray, np.ndarray]:
    """The part's fit turned ``turn_deg`` about the vertical through its centre (still level
    and on the table, so the prior finds it resting already; or tilted ``tilt_deg`` about a
    level axis through its centre, so the prior levels it) after the resting prior and the
    turn checks: (that pose, the true ``T_camera_object``)."""
    db, vertices, faces, T_world = part
    rgb, depth, mask = side_scene(vertices, faces, T_world, noise_m=0.0005, seed=3)
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask)
    centre = T_world[:3, :3] @ db[1].model_points.mean(axis=0) + T_world[:3, 3]
    turn = make_transform(rotation_about_axis([1, 0, 0], np.radians(tilt_deg))
                          @ rotation_about_axis([0, 0, 1], np.radians(turn_deg)), [0, 0, 0])
    turn[:3, 3] = centre - turn[:3, :3] @ centre
    T_cw = np.linalg.inv(SIDE.T_world_camera)
    ys, xs = np.nonzero(mask)
    box = (int(xs.min()), int(ys.min()), int(np.ptp(xs)) + 1, int(np.ptp(ys)) + 1)
    detection = Detection(instance_id=1, obj_id=1, view='side', box=box,
                          pose=PoseCandidate(T_camera_object=T_cw @ turn @ T_world,
                                             fitness=1.0, inlier_rmse_m=0.0))
    job = PartJob(detection, points, (1,), SIDE.T_world_camera)
    views = {'side': ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}
    check_resting_and_turns(PerceptionPipeline(templates=db, fit_params=fit), job, views,
                            {'side': mask.astype(np.int32)})
    assert job.detection.pose is not None
    return job.detection.pose.T_camera_object, T_cw @ T_world


def _off(fit: FitParams, on: bool) -> FitParams:
    return replace(fit, resting=replace(fit.resting, edge_rested_round=on))


def test_a_resting_disc_turned_off_is_turned_back_on_the_image_s_edges(disc):
    T, T_true = _checked(disc, FitParams())
    assert yaw_error_deg(T, T_true, 90.0) < 1.5
    world, true_world = SIDE.T_world_camera @ T, SIDE.T_world_camera @ T_true
    assert (world[:3, :3] @ true_world[:3, :3].T)[2, 2] == pytest.approx(1.0, abs=1e-6)


def test_a_resting_disc_far_off_in_yaw_is_searched_over_its_period(disc):
    # 30 deg off: beyond edge_yaw_deg, within half the quarter-turn period
    T, T_true = _checked(disc, FitParams(), 30.0)
    assert yaw_error_deg(T, T_true, 90.0) < 2.5
    fit = FitParams()
    fit = replace(fit, resting=replace(fit.resting, edge_round_period=False))
    T, T_true = _checked(disc, fit, 30.0)
    assert yaw_error_deg(T, T_true, 90.0) > 15.0   # at most edge_yaw_deg nearer


def test_a_tilted_disc_far_off_in_yaw_is_levelled_and_searched_over_its_period(disc):
    # tilted 6 deg: the prior levels it (not resting already), then the edges turn it
    T, T_true = _checked(disc, FitParams(), 30.0, tilt_deg=6.0)
    assert yaw_error_deg(T, T_true, 90.0) < 2.5
    world, true_world = SIDE.T_world_camera @ T, SIDE.T_world_camera @ T_true
    assert (world[:3, :3] @ true_world[:3, :3].T)[2, 2] == pytest.approx(1.0, abs=1e-6)
    fit = FitParams()
    fit = replace(fit, resting=replace(fit.resting, edge_round_levelled=False))
    T, T_true = _checked(disc, fit, 30.0, tilt_deg=6.0)
    assert yaw_error_deg(T, T_true, 90.0) > 15.0   # at most edge_yaw_deg nearer


def test_a_round_part_too_thick_to_be_flat_is_searched_as_well(disc):
    # the disc counted as thick (a flange: flat.flat_ratio below its 4.4 / 47 mm)
    fit = FitParams()
    fit = replace(fit, flat=replace(fit.flat, flat_ratio=0.05))
    T, T_true = _checked(disc, fit, 30.0)
    assert yaw_error_deg(T, T_true, 90.0) < 2.5
    fit = replace(fit, resting=replace(fit.resting, edge_round_thick=False))
    T, T_true = _checked(disc, fit, 30.0)
    assert yaw_error_deg(T, T_true, 90.0) > 15.0


def test_without_the_setting_a_resting_disc_keeps_its_yaw(disc):
    T, T_true = _checked(disc, _off(FitParams(), False))
    assert yaw_error_deg(T, T_true, 90.0) == pytest.approx(TURN_DEG, abs=0.1)


def test_a_resting_plate_is_left_to_its_outline(plate):
    # a plate's outline holds its yaw (the flat check's silhouette and hole-yaw searches)
    T, T_true = _checked(plate, FitParams())
    assert rotation_angle_deg(T[:3, :3], T_true[:3, :3]) == pytest.approx(TURN_DEG, abs=0.1)
