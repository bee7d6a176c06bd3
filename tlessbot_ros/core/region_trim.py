"""A fitted part's region trimmed to its fitted outline (issue 41).

The localiser's region of a part can hold pixels that are not the part: its shadow on the
table, a piece of the table's pattern, the ring of blurred colour around a small part, the
band a stereo camera's smoothed depth lifts beside a part's rim. They touch the part, so they
join its region, and the region's box grows past the part. The fit shows them: a rigid part
fitted where it lies projects to an outline in each view, and nothing outside that outline
can be the part.

So once every part of a frame is fitted (joined and divided regions included), each
region of a part with a pose keeps only its pixels within ``FitParams.trim_to_fit_px`` of the
fitted model's silhouette (:func:`~tlessbot_ros.core.pose.silhouette.silhouette`, in every
view of the labels the rig relates to the fitted one), and the region's box follows. A fit in
the wrong place must not cut a region down to itself: a region is trimmed only where it
covers at least :data:`MIN_SEEN` of the silhouette (the fitted part is seen where it is
fitted, :func:`~tlessbot_ros.core.two_parts.seen_share`'s reading); a part hidden under
another, or a fit shifted off its region, leaves its region as it was. The poses are not
changed.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from tlessbot_ros.core.common import mask_box
from tlessbot_ros.core.frame import Detection
from tlessbot_ros.core.part_fit import pose_stage
from tlessbot_ros.core.pose.silhouette import silhouette, window
from tlessbot_ros.core.recognise import UNKNOWN_ID

if TYPE_CHECKING:
    from tlessbot_ros.core.frame import ViewInput
    from tlessbot_ros.core.pipeline import PerceptionPipeline
    from tlessbot_ros.core.pose import ObjectTemplates

# A region is trimmed only when it covers at least this share of its fit's silhouette in
# that view: the share ``join_refit_cover`` asks of a joined region (a fit where its region is).
MIN_SEEN = 0.8


def trim_to_fits(pipeline: PerceptionPipeline, views: dict[str, ViewInput],
                 labels: dict[str, np.ndarray], detections: list[Detection], *,
                 box_mode: bool = False, margin_px: int | None = None,
                 min_seen: float = MIN_SEEN) -> list[Detection]:
    """``detections``, each fitted one's region in every view of ``labels`` trimmed to the
    pixels within ``margin_px`` (default ``FitParams.trim_to_fit_px``; 0: off) of its fitted
    silhouette there, where the region covers ``min_seen`` of it (see the module); nothing in
    ``box_mode`` (a region is the part's given box). ``labels``' arrays are replaced, not
    written into; each trimmed detection's ``box`` follows its region in its view."""
    margin = pipeline.fit_params.trim_to_fit_px if margin_px is None else margin_px
    if margin <= 0 or box_mode or pipeline.pose_estimator is None:
        return detections
    database = pose_stage(pipeline.pose_estimator).database
    for detection in detections:
        if detection.pose is None or detection.obj_id == UNKNOWN_ID or \
                detection.obj_id not in database:
            continue
        obj = database[detection.obj_id]
        for name, image in labels.items():
            T = pose_in_view(views, detection, name)
            region = image == detection.instance_id
            if T is None or not region.any():
                continue
            near = near_outline(obj, T, views[name], region, margin, min_seen)
            if near is not None and (region & ~near).any():
                labels[name] = np.where(region & ~near, 0, image).astype(image.dtype)
        if detection.view in labels:
            detection.box = mask_box(labels[detection.view] == detection.instance_id)
    return detections


def pose_in_view(views: dict[str, ViewInput], detection: Detection, name: str
                 ) -> np.ndarray | None:
    """(4, 4) ``detection``'s fitted pose in the optical frame of view ``name`` (the rig's
    extrinsics relate the views), or None: no such view, or no extrinsics to relate it."""
    assert detection.pose is not None
    if name == detection.view:
        return detection.pose.T_camera_object
    view, fitted = views.get(name), views.get(detection.view)
    if view is None or fitted is None or view.T_world_camera is None or \
            fitted.T_world_camera is None:
        return None
    T: np.ndarray = np.linalg.inv(view.T_world_camera) @ fitted.T_world_camera @ \
        detection.pose.T_camera_object
    return T


def near_outline(obj: ObjectTemplates, T_camera_object: np.ndarray, view: ViewInput,
                 region: np.ndarray, margin_px: int, min_seen: float) -> np.ndarray | None:
    """(H, W) bool: the pixels within ``margin_px`` of ``obj``'s silhouette at
    ``T_camera_object`` in ``view``; None when ``region`` (H, W) bool covers less than
    ``min_seen`` of that silhouette (or it is empty, or outside the image)."""
    points = obj.model_points.astype(np.float64)
    box = window(points, [T_camera_object], view.intrinsics, margin_px=margin_px + 1)
    if box is None:
        return None
    outline = silhouette(points, T_camera_object, view.intrinsics, box, obj.sample_spacing_m())
    x0, y0, w, h = box
    if not outline.any() or np.count_nonzero(outline & region[y0:y0 + h, x0:x0 + w]) < \
            min_seen * np.count_nonzero(outline):
        return None
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin_px + 1,) * 2)
    near = np.zeros(region.shape, bool)
    near[y0:y0 + h, x0:x0 + w] = cv2.dilate(outline.astype(np.uint8), kernel).astype(bool)
    return near


__all__ = ['MIN_SEEN', 'near_outline', 'pose_in_view', 'trim_to_fits']
