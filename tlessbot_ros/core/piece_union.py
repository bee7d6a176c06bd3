"""Two touching pieces of one part that neither piece's fit explains are fitted together once
(issue 41).

The localiser can cut a part in two touching pieces (a flat plate or a disc with holes, a
strip whose middle reads near the table on a stereo camera's smoothed depth), each about half
of it. Each piece is then fitted as the whole part, placed over its own half: the other half
lies outside the posed model's outline, so neither fit explains the other's points
(:mod:`tlessbot_ros.core.one_part`), and the part is reported twice, or once with a second,
unknown box left over.

So the fragment filter (:mod:`tlessbot_ros.core.fragments`) asks, of two neighbouring fitted
pieces of one view whose regions touch (at most ``FitParams.join_refit_gap_px`` apart) and
that neither fit explains, whether one fit of both pieces' points explains each piece: its
outline covers at least ``join_refit_cover`` of each piece's depth points and at least
``unknown_below_fitness`` of those lie on its surface, and no fewer than the piece's own fit
explains, but for ``verify_overrule_margin``. Two parts side by side fail that (one model
covers one of them, or a larger part's model covers both but explains each worse than its
own fit), one part's two halves pass it. And the other way round, the joined region must
cover ``join_refit_cover`` of the joint fit's silhouette
(:func:`~tlessbot_ros.core.two_parts.seen_share`): a larger part's model laid over two small
parts side by side lies partly on the table. The better piece keeps the joint
fit and the other piece's region joins it (:func:`~tlessbot_ros.core.one_part.join_pieces`).
The joint fit runs the pipeline's whole fit (the flat parts' checks, the resting prior) on
the labels with the two regions joined.

With ``join_refit_touching`` (:func:`touch_test`) touching pieces are asked whatever their
ROI centroids' distance (a half with a shadow or a table piece attached lies far from the
other's centroid), and so is a piece whose own fit was refused (unknown, no pose; both pieces
may be): the joint fit must then cover and explain its points by the same shares, its own fit
counting nothing.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import fields, replace
from typing import TYPE_CHECKING

import cv2
import numpy as np

from tlessbot_ros.core.flat_parts import check_fitted_part
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.part_fit import outline_shares
from tlessbot_ros.core.recognise import UNKNOWN_ID
from tlessbot_ros.core.resting_check import check_resting_and_turns
from tlessbot_ros.core.two_parts import seen_share

if TYPE_CHECKING:
    from tlessbot_ros.core.params import FitParams
    from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput

# two pieces whose points span more than this times their class's diameter are not one part
# (the depth's flying pixels at a part's rim reach a little past it)
SPAN_SLACK = 1.1
# the fields of a detection the joint fit does not fill in (they name its region)
_REGION_FIELDS = ('instance_id', 'view', 'box', 'class_score', 'class_margin')


def union_joiner(pipeline: PerceptionPipeline, views: dict[str, ViewInput],
                 labels: dict[str, np.ndarray], jobs: Sequence[PartJob]
                 ) -> Callable[[Detection, Detection], bool] | None:
    """``joins(keeper, piece)`` for the fragment filter (see the module): whether one fit of
    both detections' depth points explains each of them; when it does, ``keeper`` takes that
    fit. None when off (``join_refit_cover`` 0) or without an estimator."""
    params, estimator = pipeline.fit_params, pipeline.pose_estimator
    if estimator is None or params.join_refit_cover <= 0:
        return None
    by_detection = {id(job.detection): job for job in jobs}

    def share(detection: Detection, points: np.ndarray) -> tuple[float, float]:
        if detection.pose is None or detection.obj_id == UNKNOWN_ID:
            return 0.0, 0.0
        return outline_shares(params, points, detection.obj_id, detection.pose, estimator)

    def explains_each(fitted: Detection, pieces: Sequence[PartJob]) -> bool:
        """Whether ``fitted`` covers ``join_refit_cover`` of each piece's points and explains
        them as well as the piece's own fit, but for ``verify_overrule_margin`` (two parts
        side by side: one model explains them worse than each one's own)."""
        for piece in pieces:
            explained, covered = share(fitted, piece.points)
            own = share(piece.detection, piece.points)[0]
            if explained < max(params.unknown_below_fitness,
                               own - params.verify_overrule_margin) or \
                    covered < params.join_refit_cover:
                return False
        return True

    def joins(keeper: Detection, piece: Detection) -> bool:
        job, other = by_detection[id(keeper)], by_detection[id(piece)]
        image = labels.get(keeper.view)
        if keeper.view != piece.view or image is None or \
                not all(d.pose is not None or params.join_refit_touching and
                        d.obj_id == UNKNOWN_ID for d in (keeper, piece)) or \
                not regions_touch(image, keeper.instance_id, piece.instance_id,
                                  params.join_refit_gap_px):
            return False
        joined = joint_job(job, other)
        if span_m(joined.points) > SPAN_SLACK * max(estimator.database[c].diameter_m
                                                    for c in joined.candidates):
            return False   # longer than the part: two parts
        one_region = {view: np.where(im == piece.instance_id, keeper.instance_id,
                                     im).astype(im.dtype) for view, im in labels.items()}
        pipeline.fit_part(joined)   # then the checks the pipeline runs after each fit
        check_fitted_part(pipeline, joined, views, one_region)
        check_resting_and_turns(pipeline, joined, views, one_region)
        if not explains_each(joined.detection, (job, other)) or seen_share(
                pipeline, joined, views[keeper.view],
                one_region[keeper.view]) < params.join_refit_cover:
            return False   # (a larger part's model over two small ones lies on the table)
        adopt(keeper, joined.detection)
        return True
    return joins


def touch_test(params: FitParams, labels: dict[str, np.ndarray]
               ) -> Callable[[Detection, Detection], bool] | None:
    """``touching(a, b)`` for the fragment filter: whether two detections' regions of one
    view of ``labels`` touch (``join_refit_gap_px``). None when joining or
    ``join_refit_touching`` is off."""
    if params.join_refit_cover <= 0 or not params.join_refit_touching:
        return None

    def touching(a: Detection, b: Detection) -> bool:
        image, gap = labels.get(a.view), params.join_refit_gap_px
        return a.view == b.view and image is not None and boxes_near(a.box, b.box, gap) and \
            regions_touch(image, a.instance_id, b.instance_id, gap)
    return touching


def boxes_near(a: Sequence[int], b: Sequence[int], gap_px: int) -> bool:
    """Whether two (x, y, w, h) boxes lie at most ``gap_px`` + 1 pixels apart on both axes
    (regions farther apart cannot touch)."""
    return all(a[k] <= b[k] + b[k + 2] + gap_px + 1 and b[k] <= a[k] + a[k + 2] + gap_px + 1
               for k in (0, 1))


def joint_job(job: PartJob, other: PartJob) -> PartJob:
    """One job of two pieces of one view: ``job``'s detection (a copy, unfitted) over both
    regions' boxes, both ROI clouds; its candidates both pieces' fitted classes (``job``'s
    first), then their own candidates (a half of a part can fit a wrong class best)."""
    a, b = job.detection, other.detection
    x0, y0 = min(a.box[0], b.box[0]), min(a.box[1], b.box[1])
    x1 = max(a.box[0] + a.box[2], b.box[0] + b.box[2])
    y1 = max(a.box[1] + a.box[3], b.box[1] + b.box[3])
    detection = replace(a, box=(x0, y0, x1 - x0, y1 - y0), pose=None, second=None,
                        turned_over=False, n_points=len(job.points) + len(other.points))
    classes = tuple(dict.fromkeys(c for c in (a.obj_id, b.obj_id, *job.candidates,
                                              *other.candidates) if c != UNKNOWN_ID))
    return PartJob(detection, np.vstack([job.points, other.points]), classes,
                   job.T_world_camera, job.more_views, job.box_camera)


def span_m(points: np.ndarray) -> float:
    """A lower bound of the largest distance between two of ``points`` ((N, 3) m), at least
    half of it: the point farthest from the first's farthest point."""
    if len(points) < 2:
        return 0.0
    far = points[np.argmax(np.linalg.norm(points - points[0], axis=1))]
    return float(np.linalg.norm(points - far, axis=1).max())


def adopt(keeper: Detection, fitted: Detection) -> None:
    """``keeper`` takes ``fitted``'s class and poses (its region's fields stay its own)."""
    for f in fields(Detection):
        if f.name not in _REGION_FIELDS:
            setattr(keeper, f.name, getattr(fitted, f.name))


def regions_touch(image: np.ndarray, a: int, b: int, gap_px: int) -> bool:
    """Whether instances ``a`` and ``b`` of a label image have at most ``gap_px`` pixels
    between them (0: 8-neighbours)."""
    where = np.nonzero((image == a) | (image == b))
    if not where[0].size:
        return False
    y0, x0 = max(int(where[0].min()) - 1, 0), max(int(where[1].min()) - 1, 0)
    crop = image[y0:int(where[0].max()) + 2, x0:int(where[1].max()) + 2]
    size = 2 * max(0, int(gap_px)) + 3
    grown = cv2.dilate((crop == a).astype(np.uint8), np.ones((size, size), np.uint8))
    return bool((grown.astype(bool) & (crop == b)).any())


__all__ = ['adopt', 'boxes_near', 'joint_job', 'regions_touch', 'span_m', 'touch_test',
           'union_joiner']
