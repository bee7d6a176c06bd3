"""A region that its fit explains badly is fitted again on each half, and the better half's
fit divides it: two touching parts found as one in both views.

In a pile, parts that touch at one height are found as one region by both cameras; the region
is classified and fitted as one part. When that fit lies between the parts it explains
neither, so the division after the fit (:mod:`tlessbot_ros.core.two_parts`), which needs a fit
that explains one side and leaves the other out, does not reach them. A rigid part fitted
where it lies explains most of its own region's depth points; a region whose fit explains
less than ``FitParams.split_refit_below`` of them may hold more than one part. Its depth
points are cut in two on the table (two-means on their table-frame positions, seeded at
the two ends of their long axis), each half is classified and fitted alone, and the half's
fit that explains the most of the whole region's points (a part's region cut off centre still
holds most of that part) takes the region's fit in its place, whatever the first fit explained
(a part beside another explains about its own share of the region, and a fit between them can
explain as much). With it the division after the
fit runs as for any region (:func:`~tlessbot_ros.core.two_parts.split_off`, thick parts
too), with all its checks; where it divides nothing, the region keeps its first fit.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.common import depth_to_points, mask_box, transform_points
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.part_fit import pose_stage
from tlessbot_ros.core.recognise import UNKNOWN_ID
from tlessbot_ros.core.two_parts import divided_job, explained, fits_alone, split_off, split_then

if TYPE_CHECKING:
    from tlessbot_ros.core.frame import ViewInput
    from tlessbot_ros.core.pipeline import PerceptionPipeline

# the two-means on the halves' table positions: this many rounds (it settles in a few)
_ROUNDS = 10
# the fields of a fit that the better half lends the region (its place, class and scores)
_KEPT_FIELDS = ('instance_id', 'view', 'box', 'n_points')


def two_halves(region: np.ndarray, depth_m: np.ndarray, K: np.ndarray,
               T_world_camera: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The depth pixels of ``region`` ((H, W) bool) cut in two by two-means on their
    table-frame (x, y) positions, seeded at the two ends of their long axis: two (H, W) bool
    masks, or None when the region has fewer than two depth points. ``depth_m`` (H, W) m,
    ``K`` (3, 3), ``T_world_camera`` (4, 4) the view's table frame."""
    box = mask_box(region)
    if box[2] == 0:
        return None
    points, pixels = depth_to_points(depth_m, K, mask=region, box=box)
    if len(points) < 2:
        return None
    xy = transform_points(T_world_camera, points.astype(np.float64))[:, :2]
    centred = xy - xy.mean(axis=0)
    along = centred @ np.linalg.svd(centred, full_matrices=False)[2][0]
    centres = xy[[int(np.argmin(along)), int(np.argmax(along))]]
    side = np.zeros(len(xy), bool)
    for _ in range(_ROUNDS):
        side = np.linalg.norm(xy - centres[1], axis=1) < np.linalg.norm(xy - centres[0], axis=1)
        if side.all() or not side.any():
            return None
        centres = np.stack([xy[~side].mean(axis=0), xy[side].mean(axis=0)])
    halves = []
    for chosen in (~side, side):
        mask = np.zeros(region.shape, bool)
        mask[pixels[chosen, 0], pixels[chosen, 1]] = True
        halves.append(mask)
    return halves[0], halves[1]


def explained_share(pipeline: PerceptionPipeline, job: PartJob,
                    points: np.ndarray | None = None) -> float:
    """The share of ``points`` ((N, 3) in ``job``'s view; default its own) that its fit
    explains (:func:`~tlessbot_ros.core.two_parts.explained`, at ``verify_inlier_m``; 0
    without a pose or class)."""
    pose, points = job.detection.pose, job.points if points is None else points
    if pose is None or job.detection.obj_id == UNKNOWN_ID or not len(points):
        return 0.0
    estimator = pose_stage(pipeline.pose_estimator)
    return float(explained(np.asarray(points, np.float64),
                           estimator.database[job.detection.obj_id], pose.T_camera_object,
                           estimator.refiner, pipeline.fit_params.verify_inlier_m).mean())


def better_half(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                labels: dict[str, np.ndarray]) -> PartJob | None:
    """Of ``job``'s region cut in two (:func:`two_halves`, in its fitted view), the half,
    classified and fitted alone, whose fit is a part (:func:`fits_alone`) and explains the
    most of the region's points; None when neither is a part. (A part beside another
    explains about its own share of the region, which a fit between them can exceed.)"""
    detection = job.detection
    view = views[detection.view]
    if view.depth_m is None or job.T_world_camera is None:
        return None
    halves = two_halves(labels[detection.view] == detection.instance_id, view.depth_m,
                        view.intrinsics.K, job.T_world_camera)
    if halves is None:
        return None
    new_id = 1 + max(int(image.max(initial=0)) for image in labels.values())
    if new_id > np.iinfo(labels[detection.view].dtype).max:
        return None
    best, best_share = None, -1.0
    for half in halves:
        cut = dict(labels)
        cut[detection.view] = np.where(half, new_id, labels[detection.view]).astype(
            labels[detection.view].dtype)
        side = divided_job(pipeline, job, views, cut, new_id)
        if side is None or not fits_alone(pipeline, side):
            continue
        share = explained_share(pipeline, side, job.points)
        if share > best_share:
            best, best_share = side, share
    return best


def split_badly_explained(pipeline: PerceptionPipeline, job: PartJob,
                          views: dict[str, ViewInput], labels: dict[str, np.ndarray],
                          others: Sequence[PartJob] = ()) -> PartJob | None:
    """The division after the fit (:func:`~tlessbot_ros.core.two_parts.split_off`, thick
    parts too) of a region whose fit explains less than ``FitParams.split_refit_below`` of
    its depth points, made from the fit of its better half (:func:`better_half`; see the
    module): the piece divided off, ``labels`` and ``job`` then as ``split_off`` leaves
    them; else None and ``job`` keeps its first fit."""
    below = pipeline.fit_params.split_refit_below
    if below <= 0 or job.detection.pose is None or job.detection.obj_id == UNKNOWN_ID or \
            explained_share(pipeline, job) >= below:
        return None
    half = better_half(pipeline, job, views, labels)
    if half is None:
        return None
    first, candidates = dict(vars(job.detection)), job.candidates
    vars(job.detection).update({name: value for name, value in vars(half.detection).items()
                                if name not in _KEPT_FIELDS})
    job.candidates = half.candidates
    piece = split_off(pipeline, job, views, labels, others, thick_too=True)
    if piece is None:
        vars(job.detection).update(first)
        job.candidates = candidates
    return piece


def split_or_refit(pipeline: PerceptionPipeline, views: dict[str, ViewInput],
                   labels: dict[str, np.ndarray], jobs: Sequence[PartJob],
                   judge: Callable[[Detection], None], publish: Callable[[Detection], None], *,
                   box_mode: bool = False) -> tuple[Callable[[Detection], None], list[Detection]]:
    """:func:`~tlessbot_ros.core.two_parts.split_then` with :func:`split_badly_explained` as
    its second try where the first division finds no piece."""
    return split_then(pipeline, views, labels, jobs, judge, publish, box_mode=box_mode,
                      second_try=split_badly_explained)


__all__ = ['better_half', 'explained_share', 'split_badly_explained', 'split_or_refit',
           'two_halves']
