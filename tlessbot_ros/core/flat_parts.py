"""Flat parts in the composed pipeline: the mirror check of a fitted part over every view.

:func:`check_mirror` gathers what each camera shows of a fitted part (colour, the localiser's
label, the rig's transform from the fitted view) and lets
:class:`~tlessbot_ros.core.pose.mirror.MirrorCheck` turn a flat part over when the image
shows the other face up.
"""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.pose.mirror import MirrorCheck, ViewEvidence

if TYPE_CHECKING:
    from tlessbot_ros.core.pipeline import PartJob, PerceptionPipeline, ViewInput


def mirror_views(views: dict[str, ViewInput], labels: dict[str, np.ndarray], instance: int,
                 fit_view: str) -> list[ViewEvidence]:
    """The :class:`ViewEvidence` of part ``instance`` fitted in ``fit_view``: that view, and
    every other view with colour, the part's label and rig extrinsics for both."""
    out = []
    T_fit = views[fit_view].T_world_camera
    for name, view in views.items():
        if name not in labels:
            continue
        if name == fit_view:
            T_view_fit = np.eye(4)
        elif T_fit is None or view.T_world_camera is None:
            continue
        else:
            T_view_fit = np.linalg.inv(view.T_world_camera) @ T_fit
        out.append(ViewEvidence(view.rgb, labels[name] == instance, view.intrinsics,
                                T_view_fit))
    return out


def check_mirror(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                 labels: dict[str, np.ndarray]) -> dict[str, float] | None:
    """Turn ``job``'s fitted flat part over when the image shows the other face up
    (``FitParams.mirror``); the former pose becomes the detection's ``second``. Returns what
    decided (None when the part is not checked)."""
    detection = job.detection
    estimator = pipeline.pose_estimator
    if estimator is None or detection.pose is None or job.T_world_camera is None:
        return None
    obj = estimator.database[detection.obj_id]
    cloud = estimator.params.cloud
    check = MirrorCheck(estimator.refiner, pipeline.fit_params.mirror,
                        voxel_scale=estimator.params.table_voxel_scale,
                        sor_neighbors=cloud.sor_neighbors, sor_std_ratio=cloud.sor_std_ratio)
    if not check.applies(obj):
        return None
    T, info = check.resolve(obj, detection.pose.T_camera_object, job.points, job.T_world_camera,
                            mirror_views(views, labels, detection.instance_id, detection.view))
    if T is not None:
        detection.second = detection.pose
        detection.pose = replace(detection.pose, T_camera_object=T,
                                 fitness=info['flip_fitness'])
    return info
