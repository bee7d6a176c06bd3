"""The resting-pose prior in the composed pipeline: a fitted part that sits on the table is
levelled onto the nearest stable pose of its part when that fits its depth as well
(:func:`~tlessbot_ros.core.pose.resting.settle`, ``FitParams.resting``) and the aligned
height and colour votes of its views do not clearly prefer the free fit."""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.common import plane_of_frame
from tlessbot_ros.core.flat_parts import colour_views, flat_check, table_frames
from tlessbot_ros.core.pose.flat_align import table_noise_m
from tlessbot_ros.core.pose.flat_turns import mesh_scene
from tlessbot_ros.core.pose.rest_edges import refine_on_edges
from tlessbot_ros.core.pose.resting import level_starts, settle
from tlessbot_ros.core.turn_check import check_turns

if TYPE_CHECKING:

    from tlessbot_ros.core.frame import Detection, PartJob, ViewInput
    from tlessbot_ros.core.pipeline import PerceptionPipeline


def check_resting(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                  labels: dict[str, np.ndarray]) -> dict[str, float] | None:
    """Level ``job``'s fit onto a stable pose of its part (:func:`settle`) unless the aligned
    votes of its views (those with a table frame) clearly choose the free fit; the free fit
    becomes the detection's ``second``. Returns what decided (None when not checked: the
    prior off, no fit or no table frame)."""
    detection = job.detection
    estimator = pipeline.pose_estimator
    params = pipeline.fit_params.resting
    if not params.enabled or estimator is None or detection.pose is None or \
            job.T_world_camera is None:
        return None
    obj = estimator.database[detection.obj_id]
    T_free = detection.pose.T_camera_object
    starts, info = level_starts(obj, job.T_world_camera @ T_free, params)
    if not len(starts):
        return info   # nothing to try: the ROI cloud is not prepared
    check = flat_check(pipeline)
    scene_c = check.prepared_cloud(obj, job.points)
    noise_m = _table_noise(views, labels, detection, job.T_world_camera) \
        if params.noise_ratio > 0 else 0.0
    T, info = settle(estimator.refiner, obj, T_free, scene_c, job.T_world_camera, params,
                     noise_m=noise_m)
    info['rest_noise_m'] = noise_m
    if T is None:
        return info
    mesh = mesh_scene(obj)
    evidence = colour_views(views, labels, detection.instance_id, detection.view,
                            table_frames(pipeline, views))
    if mesh is not None and any(v.plane is not None for v in evidence):
        found: dict[str, float] = {}
        check.aligned_winner(obj, [mesh, mesh], [T_free, T], evidence, found)
        if found.get('align_decided') and found.get('align_winner') == 0.0:
            info['rest_levelled'] = 0.0
            info['rest_votes_kept'] = 1.0
            return info
    detection.second = detection.pose
    fitness = float(estimator.refiner.grid_fitness(T[None], scene_c, obj)[0])
    detection.pose = replace(detection.pose, T_camera_object=T, fitness=fitness)
    return info


def refine_levelled(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                    labels: dict[str, np.ndarray], info: dict[str, float]) -> None:
    """Turn and move ``job``'s levelled pose on the table where its edges lie best on the
    image's (:func:`refine_on_edges`, ``resting.edge_*``) unless the move explains more than
    ``fitness_margin`` fewer of its depth points (a neighbour's edges, a shadow, can pull it
    off its own depth); ``info`` (:func:`check_resting`'s, levelled) gets what decided."""
    estimator, params = pipeline.pose_estimator, pipeline.fit_params.resting
    detection = job.detection
    if estimator is None or detection.pose is None or job.T_world_camera is None or \
            params.edge_yaw_deg <= 0:
        return
    obj = estimator.database[detection.obj_id]
    mesh = mesh_scene(obj)
    if mesh is None:
        return
    evidence = colour_views(views, labels, detection.instance_id, detection.view)
    T = detection.pose.T_camera_object
    moved, found = refine_on_edges(
        mesh, T, job.T_world_camera, obj.model_points.astype(np.float64), evidence,
        max_yaw_deg=params.edge_yaw_deg, max_shift_m=params.edge_shift_m,
        cap_px=params.edge_cap_px, jump_m=params.tolerance_m, crease_deg=30.0)
    info.update(found)
    if found['edge_yaw_deg'] == 0.0 and found['edge_shift_m'] == 0.0:
        return
    scene_c = flat_check(pipeline).prepared_cloud(obj, job.points)
    tolerance = info.get('rest_tolerance_m', params.tolerance_m)
    fits = [estimator.refiner.surface_fit(scene_c, obj, P, inlier_m=tolerance)[0]
            for P in (T, moved)]
    info['edge_fitness'] = fits[1]
    if fits[1] >= fits[0] - params.fitness_margin:
        fitness = float(estimator.refiner.grid_fitness(moved[None], scene_c, obj)[0])
        detection.pose = replace(detection.pose, T_camera_object=moved, fitness=fitness)


def _table_noise(views: dict[str, ViewInput], labels: dict[str, np.ndarray],
                 detection: Detection, T_world_camera: np.ndarray) -> float:
    """The depth noise shared by neighbouring pixels on the table around ``detection`` in
    its view (:func:`table_noise_m`; 0 without that view's depth or labels)."""
    view, label = views.get(detection.view), labels.get(detection.view)
    if view is None or view.depth_m is None or label is None:
        return 0.0
    return table_noise_m(view.depth_m, view.intrinsics, detection.box,
                         plane_of_frame(T_world_camera), label != 0)


def check_resting_and_turns(pipeline: PerceptionPipeline, job: PartJob,
                            views: dict[str, ViewInput], labels: dict[str, np.ndarray]) -> None:
    """The resting prior (:func:`check_resting`), then the near-symmetric turns
    (:func:`~tlessbot_ros.core.turn_check.check_turns`: they compare turns of a levelled pose),
    then the prior again when a turn changed the pose (a refitted half turn may tilt it); a
    pose levelled last is then refined on the image's edges (:func:`refine_levelled`: after
    the turns, which compare turns of the pose as the depth left it)."""
    info = check_resting(pipeline, job, views, labels)
    before = job.detection.pose
    check_turns(pipeline, job, views, labels)
    if job.detection.pose is not before:
        info = check_resting(pipeline, job, views, labels)
    if info is not None and info.get('rest_levelled') == 1.0:
        refine_levelled(pipeline, job, views, labels, info)


__all__ = ['check_resting', 'check_resting_and_turns', 'refine_levelled']
