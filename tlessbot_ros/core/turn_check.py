"""Near-symmetric parts in the composed pipeline: a fitted part turned where the colour image
shows its features better (:func:`~tlessbot_ros.core.pose.turns.choose_turn`,
``FitParams.turns``). Flat parts have their own check (:mod:`tlessbot_ros.core.flat_parts`)."""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.flat_parts import colour_views
from tlessbot_ros.core.pose.flat import is_flat, mesh_scene
from tlessbot_ros.core.pose.turns import choose_turn

if TYPE_CHECKING:
    from tlessbot_ros.core.frame import PartJob, ViewInput
    from tlessbot_ros.core.pipeline import PerceptionPipeline


def check_turns(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                labels: dict[str, np.ndarray]) -> dict[str, float] | None:
    """Replace ``job``'s fitted pose by a near-symmetric turn of it when the colour views
    support the turn's edges clearly better; the former pose becomes the detection's
    ``second``. Runs on parts that are not flat and whose templates hold their mesh. Returns
    what decided (None when the part is not checked)."""
    detection = job.detection
    estimator = pipeline.pose_estimator
    params = pipeline.fit_params.turns
    if not params.enabled or estimator is None or detection.pose is None:
        return None
    obj = estimator.database[detection.obj_id]
    scene = mesh_scene(obj)
    if scene is None or (pipeline.fit_params.flat.enabled and
                         is_flat(obj, pipeline.fit_params.flat.flat_ratio)):
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
    return info
