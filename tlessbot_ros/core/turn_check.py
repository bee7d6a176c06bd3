"""Near-symmetric parts in the composed pipeline: a fitted part turned where the colour image
shows its features better (:func:`~tlessbot_ros.core.pose.turns.choose_turn`,
``FitParams.turns``). Flat parts have their own check (:mod:`tlessbot_ros.core.flat_parts`)."""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.flat_parts import colour_views, flat_check, table_frames
from tlessbot_ros.core.pose.flat_params import is_flat
from tlessbot_ros.core.pose.flat_turns import mesh_scene
from tlessbot_ros.core.pose.half_turns import choose_half_turn, self_half_turns
from tlessbot_ros.core.pose.turns import TurnParams, choose_turn, near_turns

if TYPE_CHECKING:
    from tlessbot_ros.core.frame import PartJob, ViewInput
    from tlessbot_ros.core.params import FitParams
    from tlessbot_ros.core.pipeline import PerceptionPipeline
    from tlessbot_ros.core.pose import ObjectTemplates, TemplateDatabase


def _checked(obj: ObjectTemplates, fit: FitParams) -> bool:
    """Whether the turn check runs on ``obj``: on, a mesh, not a flat part."""
    return fit.turns.enabled and mesh_scene(obj) is not None and not (
        fit.flat.enabled and is_flat(obj, fit.flat.flat_ratio))


def warm_up_turns(database: TemplateDatabase, fit: FitParams, *, colour: bool = True) -> None:
    """List every checked part's near-symmetric turns now (once per part), so the
    first frame that shows it is not slower than the next; nothing without ``colour`` views
    (the check needs them: a pose node without colour input would list them for nothing)."""
    if not colour:
        return
    p: TurnParams = fit.turns
    for obj in database.objects.values():
        if _checked(obj, fit):
            near_turns(obj, step_deg=p.step_deg, min_turn_deg=p.min_turn_deg,
                       near_ratio=p.near_ratio, exact_ratio=p.exact_ratio,
                       exact_quantile=p.exact_quantile)
            if p.half_turns:
                self_half_turns(obj, min_share=p.half_min_share, exact_ratio=p.exact_ratio,
                                exact_quantile=p.exact_quantile)


def check_turns(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                labels: dict[str, np.ndarray]) -> dict[str, float] | None:
    """Replace ``job``'s fitted pose by a near-symmetric turn of it when the colour views
    support the turn's edges clearly better; the former pose becomes the detection's
    ``second``. Runs on parts that are not flat and whose templates hold their mesh. Returns
    what decided (None when the part is not checked)."""
    detection = job.detection
    estimator = pipeline.pose_estimator
    params = pipeline.fit_params.turns
    if estimator is None or detection.pose is None:
        return None
    obj = estimator.database[detection.obj_id]
    scene = mesh_scene(obj)
    if scene is None or not _checked(obj, pipeline.fit_params):
        return None
    evidence = colour_views(views, labels, detection.instance_id, detection.view)
    if not evidence:
        return None
    points = np.asarray(job.points, np.float64)
    points = points[::max(1, int(np.ceil(len(points) / params.points)))]

    def fitness(T: np.ndarray) -> np.ndarray:
        return estimator.refiner.grid_fitness(T, points, obj)

    T, info = choose_turn(obj, scene, detection.pose.T_camera_object, evidence, fitness, params)
    if info['turned_deg'] > 0:
        detection.second = detection.pose
        detection.pose = replace(detection.pose, T_camera_object=T)
    if params.half_turns:
        info.update(check_half_turns(pipeline, job, views, labels))
    return info


def check_half_turns(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                     labels: dict[str, np.ndarray]) -> dict[str, float]:
    """Replace ``job``'s pose by a refitted half turn of it that the aligned height and colour
    votes of every view choose clearly (:func:`~.pose.half_turns.choose_half_turn`; views
    with a table frame); the former pose becomes the detection's ``second``."""
    detection = job.detection
    estimator = pipeline.pose_estimator
    assert estimator is not None and detection.pose is not None
    obj = estimator.database[detection.obj_id]
    check = flat_check(pipeline)
    evidence = colour_views(views, labels, detection.instance_id, detection.view,
                            table_frames(pipeline, views))
    scene_c = check.prepared_cloud(obj, job.points)
    if len(scene_c) < 10:
        return {}
    T, info = choose_half_turn(check, obj, detection.pose.T_camera_object, scene_c, evidence,
                               pipeline.fit_params.turns)
    if info['half_winner'] > 0:
        detection.second = detection.pose
        detection.pose = replace(detection.pose, T_camera_object=T)
    return info
