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
from tlessbot_ros.core.pose.flat_yaw import hole_yaw_period, thin_axis
from tlessbot_ros.core.pose.rest_edges import refine_on_edges
from tlessbot_ros.core.pose.resting import level_starts, rest_tolerance_m, settle
from tlessbot_ros.core.turn_check import check_turns

if TYPE_CHECKING:
    import open3d as o3d

    from tlessbot_ros.core.frame import Detection, PartJob, ViewInput
    from tlessbot_ros.core.pipeline import PerceptionPipeline
    from tlessbot_ros.core.pose.database import ObjectTemplates
    from tlessbot_ros.core.pose.flat import FlatCheck, ViewEvidence
    from tlessbot_ros.core.pose.refinement import Refiner
    from tlessbot_ros.core.pose.resting import RestingParams

# a disc's thin axis within this of the vertical lies on a face; beyond, it stands on its rim
# (its stable poses are one or the other: 0 or 90 deg)
_LYING_AXIS_DEG = 45.0


def check_resting(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                  labels: dict[str, np.ndarray]) -> dict[str, float] | None:
    """Level ``job``'s fit onto a stable pose of its part (:func:`settle`) unless the aligned
    votes of its views (those with a table frame) clearly choose the free fit; the free fit
    becomes the detection's ``second``. Returns what decided (None when not checked: the
    prior off, no fit or no table frame)."""
    return _level(pipeline, job, views, labels)[0]


def _level(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
           labels: dict[str, np.ndarray]
           ) -> tuple[dict[str, float] | None, tuple[np.ndarray, np.ndarray] | None]:
    """:func:`check_resting`, and the levelled pose refined on the image's edges
    (:func:`_on_edges`) with the prepared ROI cloud ((N, 3) m, camera frame) it was fitted to
    (None when not levelled): the votes weigh it against the free fit, as the pose the part
    is given at last; the detection gets the levelled pose as the depth left it, for the turn
    checks. A round flat part's fit that rests already comes back refined the same way
    (:func:`_rested_on_edges`), its pose left as it was for the turn checks."""
    detection = job.detection
    estimator = pipeline.pose_estimator
    params = pipeline.fit_params.resting
    if not params.enabled or estimator is None or detection.pose is None or \
            job.T_world_camera is None:
        return None, None
    obj = estimator.database[detection.obj_id]
    T_free = detection.pose.T_camera_object
    starts, info = level_starts(obj, job.T_world_camera @ T_free, params)
    if not len(starts):   # nothing to level: the ROI cloud is not prepared
        return info, _rested_on_edges(pipeline, job, views, labels, info)
    check = flat_check(pipeline)
    scene_c = check.prepared_cloud(obj, job.points)
    noise_m = _table_noise(views, labels, detection, job.T_world_camera, params)
    T, info = settle(estimator.refiner, obj, T_free, scene_c, job.T_world_camera, params,
                     noise_m=noise_m)
    info['rest_noise_m'] = noise_m
    if T is None:
        return info, None
    mesh = mesh_scene(obj)
    evidence = colour_views(views, labels, detection.instance_id, detection.view,
                            table_frames(pipeline, views))
    reach_deg = _round_reach_deg(check, obj, job.T_world_camera @ T, params) \
        if params.edge_round_levelled else params.edge_yaw_deg
    refined = T if mesh is None or params.edge_yaw_deg <= 0 else \
        _on_edges(estimator.refiner, obj, mesh, T, scene_c, job, evidence, params, info,
                  max_yaw_deg=reach_deg)
    if mesh is not None and _votes_keep(check, obj, mesh, T_free, refined, evidence):
        info['rest_levelled'] = 0.0
        info['rest_votes_kept'] = 1.0
        return info, None
    detection.second = detection.pose
    fitness = float(estimator.refiner.grid_fitness(T[None], scene_c, obj)[0])
    detection.pose = replace(detection.pose, T_camera_object=T, fitness=fitness)
    return info, (refined, scene_c)


def _rested_on_edges(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                     labels: dict[str, np.ndarray], info: dict[str, float]
                     ) -> tuple[np.ndarray, np.ndarray] | None:
    """A round flat part's fit (a disc with holes, :func:`hole_yaw_period`) that rests on a
    face already (within ``min_tilt_deg``, on the table), refined on the image's edges as a
    levelled pose is (:func:`_on_edges`; ``resting.edge_rested_round``): only its holes hold
    its yaw, and a smoothed depth does not show them. Returns the refined pose with the
    prepared ROI cloud, or None (not refined, not moved, or the aligned votes of the views
    clearly keep the fit); ``info`` gets what decided."""
    estimator, params = pipeline.pose_estimator, pipeline.fit_params.resting
    assert estimator is not None and job.detection.pose is not None
    if not params.edge_rested_round or params.edge_yaw_deg <= 0 or \
            info['rest_tilt_deg'] > params.min_tilt_deg or \
            abs(info['rest_contact_m']) > params.contact_m:
        return None
    obj = estimator.database[job.detection.obj_id]
    mesh = mesh_scene(obj)
    check = flat_check(pipeline)
    if mesh is None or not _round_part(check, obj, params):
        return None
    T_fit = job.detection.pose.T_camera_object
    scene_c = check.prepared_cloud(obj, job.points)
    noise_m = _table_noise(views, labels, job.detection, job.T_world_camera, params)
    tolerance = rest_tolerance_m(params, noise_m)
    info.update(rest_noise_m=noise_m, rest_tolerance_m=tolerance, rest_best_fitness=float(
        estimator.refiner.surface_fit(scene_c, obj, T_fit, inlier_m=tolerance)[0]))
    evidence = colour_views(views, labels, job.detection.instance_id, job.detection.view,
                            table_frames(pipeline, views))
    reach_deg = _round_reach_deg(check, obj, job.T_world_camera @ T_fit, params)
    refined = _on_edges(estimator.refiner, obj, mesh, T_fit, scene_c, job, evidence, params,
                        info, max_yaw_deg=reach_deg)
    if refined is T_fit:
        return None
    if _votes_keep(check, obj, mesh, T_fit, refined, evidence):
        info['rest_votes_kept'] = 1.0
        return None
    info['rest_edge_rested'] = 1.0
    return refined, scene_c


def _round_part(check: FlatCheck, obj: ObjectTemplates, params: RestingParams) -> bool:
    """Whether ``obj`` is a round part whose holes alone hold its yaw (:func:`hole_yaw_period`):
    a flat one, or a thicker one (a flange) with ``edge_round_thick``."""
    return hole_yaw_period(obj) > 0 and (params.edge_round_thick or check.applies(obj))


def _round_reach_deg(check: FlatCheck, obj: ObjectTemplates, T_world_object: np.ndarray,
                     params: RestingParams) -> float:
    """How far either way the edge refinement turns a pose about the vertical (deg): half the
    listed yaw period of a round part (:func:`_round_part`) lying on a face (its thin axis
    within ``_LYING_AXIS_DEG`` of the vertical; ``edge_round_period``) where that is more than
    ``edge_yaw_deg``, else ``edge_yaw_deg``. A disc standing on its rim turns about a level
    axis: a turn about the vertical is not its period's."""
    period = hole_yaw_period(obj) if params.edge_round_period and \
        _round_part(check, obj, params) else 0.0
    if period <= 0:
        return params.edge_yaw_deg
    thin_world = T_world_object[:3, :3] @ thin_axis(obj)
    if abs(float(thin_world[2])) < np.cos(np.radians(_LYING_AXIS_DEG)):
        return params.edge_yaw_deg
    return max(params.edge_yaw_deg, float(np.degrees(period)) / 2)


def _on_edges(refiner: Refiner, obj: ObjectTemplates, mesh: o3d.t.geometry.RaycastingScene,
              T: np.ndarray, scene_c: np.ndarray, job: PartJob, evidence: list[ViewEvidence],
              params: RestingParams, info: dict[str, float], *,
              max_yaw_deg: float | None = None) -> np.ndarray:
    """The levelled pose ``T`` turned and moved on the table where its edges lie best on the
    image's (:func:`refine_on_edges`, ``resting.edge_*``), or ``T`` itself when that move
    explains more than ``fitness_margin`` fewer of its depth points (a neighbour's edges, a
    shadow, can pull it off its own depth); ``info`` gets what decided. ``max_yaw_deg``:
    the turn searched either way (None: ``edge_yaw_deg``)."""
    assert job.T_world_camera is not None
    moved, found = refine_on_edges(
        mesh, T, job.T_world_camera, obj.model_points.astype(np.float64), evidence,
        max_yaw_deg=params.edge_yaw_deg if max_yaw_deg is None else max_yaw_deg,
        max_shift_m=params.edge_shift_m,
        cap_px=params.edge_cap_px, jump_m=params.tolerance_m, crease_deg=30.0,
        min_reach_px=params.edge_min_reach_px)
    info.update(found)
    if found['edge_yaw_deg'] == 0.0 and found['edge_shift_m'] == 0.0:
        return T
    fitness, _ = refiner.surface_fit(scene_c, obj, moved, inlier_m=info['rest_tolerance_m'])
    info['edge_depth_fitness'] = fitness
    return moved if fitness >= info['rest_best_fitness'] - params.fitness_margin else T


def _votes_keep(check: FlatCheck, obj: ObjectTemplates,
                mesh: o3d.t.geometry.RaycastingScene, T_kept: np.ndarray, T_new: np.ndarray,
                evidence: list[ViewEvidence]) -> bool:
    """Whether the aligned height and colour votes of the views with a table frame clearly
    choose the pose ``T_kept`` over ``T_new`` (:meth:`~.flat.FlatCheck.aligned_winner`)."""
    if not any(v.plane is not None for v in evidence):
        return False
    found: dict[str, float] = {}
    check.aligned_winner(obj, [mesh, mesh], [T_kept, T_new], evidence, found)
    return bool(found.get('align_decided')) and found.get('align_winner') == 0.0


def _table_noise(views: dict[str, ViewInput], labels: dict[str, np.ndarray],
                 detection: Detection, T_world_camera: np.ndarray | None,
                 params: RestingParams) -> float:
    """The depth noise shared by neighbouring pixels on the table around ``detection`` in
    its view (:func:`table_noise_m`; 0 when ``params.noise_ratio`` does not use it, or
    without a table frame or that view's depth or labels)."""
    view, label = views.get(detection.view), labels.get(detection.view)
    if params.noise_ratio <= 0 or T_world_camera is None or view is None or \
            view.depth_m is None or label is None:
        return 0.0
    return table_noise_m(view.depth_m, view.intrinsics, detection.box,
                         plane_of_frame(T_world_camera), label != 0)


def check_resting_and_turns(pipeline: PerceptionPipeline, job: PartJob,
                            views: dict[str, ViewInput], labels: dict[str, np.ndarray]) -> None:
    """The resting prior (:func:`check_resting`), then the near-symmetric turns
    (:func:`~tlessbot_ros.core.turn_check.check_turns`: they compare turns of a levelled pose
    as the depth left it: a pose refined on the image would outscore its unrefined turns),
    then the prior again when a turn changed the pose (a refitted half turn may tilt it).
    A levelled pose (or a round flat part's resting fit) that no turn changed is then the one
    refined on the image's edges."""
    _, refined = _level(pipeline, job, views, labels)
    levelled = before = job.detection.pose
    check_turns(pipeline, job, views, labels)
    if job.detection.pose is not before:
        _, refined = _level(pipeline, job, views, labels)
        levelled = job.detection.pose
    pose = job.detection.pose
    if refined is not None and pose is levelled and pose is not None and \
            refined[0] is not pose.T_camera_object:
        estimator = pipeline.pose_estimator
        assert estimator is not None
        T, scene_c = refined
        obj = estimator.database[job.detection.obj_id]
        fitness = float(estimator.refiner.grid_fitness(T[None], scene_c, obj)[0])
        job.detection.pose = replace(pose, T_camera_object=T, fitness=fitness)


__all__ = ['check_resting', 'check_resting_and_turns']
