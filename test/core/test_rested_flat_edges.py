"""A flat part whose fit rests on a face already (level within ``resting.min_tilt_deg``) but is
turned a few degrees about the vertical: the depth of a plate holds its height and tilt, not its
yaw, so the resting prior refines it on the image's edges as it does a pose it levelled
(``resting.edge_rested_flat``; off, the fit stays as it was)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from side_scene import SIDE, holed_plate, side_scene

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

TURN_DEG = 4.0   # the fit's yaw error: a 60 mm plate's corners move 2 mm, 2 px at 0.6 m


@pytest.fixture(scope='module')
def scene():
    """The 60 x 40 x 4 mm holed plate lying flat in the side view: (its templates, its true
    ``T_camera_object``, the view, its label image, its ROI cloud)."""
    v, f = holed_plate()
    poses = resting_poses(v, f, float(np.linalg.norm(np.ptp(v, axis=0))))
    db = build_database([(1, v, f, poses, None)], intrinsics=SIDE.intrinsics,
                        T_world_camera=SIDE.T_world_camera)
    flat = next(T for T, _ in poses if abs(T[:3, :3][2, 2]) > 0.99)   # its 4 mm axis up
    T_true = make_transform(rotation_about_axis([0, 0, 1], np.radians(20.0)),
                            [0.0, 0.0, 0.0]) @ flat
    rgb, depth, mask = side_scene(v, f, T_true, noise_m=0.0)
    points = depth_to_points(np.where(mask, depth, 0), SIDE.intrinsics.K)[0]
    view = ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)
    return db, np.linalg.inv(SIDE.T_world_camera) @ T_true, view, mask.astype(np.int32), points


def _turned_fit(db, T_true_c: np.ndarray, yaw_deg: float) -> np.ndarray:
    """``T_true_c`` turned by ``yaw_deg`` about the vertical through the plate's centre: still
    level and on the table, so the prior finds it resting already."""
    T_cw = np.linalg.inv(SIDE.T_world_camera)
    T_world = SIDE.T_world_camera @ T_true_c
    centre = T_world[:3, :3] @ db[1].model_points.mean(axis=0) + T_world[:3, 3]
    turn = make_transform(rotation_about_axis([0, 0, 1], np.radians(yaw_deg)), [0, 0, 0])
    turn[:3, 3] = centre - turn[:3, :3] @ centre
    return T_cw @ turn @ T_world


def _checked(scene, fit: FitParams) -> np.ndarray:
    db, T_true_c, view, labels, points = scene
    ys, xs = np.nonzero(labels)
    box = (int(xs.min()), int(ys.min()), int(np.ptp(xs)) + 1, int(np.ptp(ys)) + 1)
    T_fit = _turned_fit(db, T_true_c, TURN_DEG)
    detection = Detection(instance_id=1, obj_id=1, view='side', box=box,
                          pose=PoseCandidate(T_camera_object=T_fit, fitness=1.0,
                                             inlier_rmse_m=0.0))
    job = PartJob(detection, points, (1,), SIDE.T_world_camera)
    pipeline = PerceptionPipeline(templates=db, fit_params=fit)
    check_resting_and_turns(pipeline, job, {'side': view}, {'side': labels})
    assert job.detection.pose is not None
    return job.detection.pose.T_camera_object


def test_a_resting_flat_fit_turned_off_is_turned_back_on_the_image_s_edges(scene):
    _, T_true_c, *_ = scene
    T = _checked(scene, FitParams())
    assert rotation_angle_deg(T[:3, :3], T_true_c[:3, :3]) < 1.0
    world = SIDE.T_world_camera @ T   # turned about the vertical only: still level
    true_world = SIDE.T_world_camera @ T_true_c
    assert (world[:3, :3] @ true_world[:3, :3].T)[2, 2] == pytest.approx(1.0, abs=1e-6)


def test_without_the_setting_a_resting_fit_keeps_its_yaw(scene):
    _, T_true_c, *_ = scene
    fit = FitParams()
    T = _checked(scene, replace(fit, resting=replace(fit.resting, edge_rested_flat=False)))
    assert rotation_angle_deg(T[:3, :3], T_true_c[:3, :3]) == pytest.approx(TURN_DEG, abs=0.1)
