"""One part found as two instances is joined after the fit (issue 41).

The two-view fusion divides a side instance where the top camera sees two blobs (a part whose
two ends the top sees apart: T-LESS obj_08's sockets, a bracket's flange and upright, the
SyGrid T-wrench); it is right far more often than not, and nothing in the images before the
fit tells the wrong divisions from the right ones. After the fit it shows: one piece is fitted
as the whole part, and that fit explains the other piece's depth points as well.

So a fitted part *explains* a neighbouring region when its fit would pass the unknown rule
(:func:`~tlessbot_ros.core.part_fit.unknown_last`) on that region's points as on its own:
at least ``unknown_below_cover`` of them inside the posed model's outline and at least
``unknown_below_fitness`` of those within ``verify_inlier_m`` of its surface. A part beside
it lies outside its outline, or inside but off its surface (in front or behind). The fragment
filter (:mod:`tlessbot_ros.core.fragments`) then drops the explained piece, and
:func:`join_pieces` gives its region (in every view) to the part that explained it, so the
part is reported once, with the whole region's box.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from tlessbot_ros.core.common import mask_box, transform_points
from tlessbot_ros.core.edge_bands import band_test, without_label
from tlessbot_ros.core.fragments import FragmentFilter, fragment_filter
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.part_fit import outline_shares, pose_stage
from tlessbot_ros.core.pose import PoseEstimator
from tlessbot_ros.core.recognise import UNKNOWN_ID
from tlessbot_ros.core.same_part import same_part_test


def one_part_filter(jobs: Sequence[PartJob], publish: Callable[[Detection], None],
                    params: FitParams, estimator: PoseEstimator | None, overlap: float,
                    joins: Callable[[Detection, Detection], bool] | None = None,
                    touching: Callable[[Detection, Detection], bool] | None = None, *,
                    labels: dict[str, np.ndarray] | None = None
                    ) -> FragmentFilter[Detection]:
    """The frame's fragment filter (:func:`~tlessbot_ros.core.fragments.fragment_filter`,
    ``overlap``) that also drops a piece another part's fit explains (:func:`explainer`), or
    one fit of both explains (``joins`` of ``touching`` pieces,
    :mod:`tlessbot_ros.core.piece_union`), or (with the frame's ``labels``) a band of them
    along a fitted part's edge (``FitParams.edge_band_px``, :mod:`.edge_bands`), or one whose
    fit fills the same space as a better fit of its class (``FitParams.same_part_share``,
    :mod:`.same_part`)."""
    band = band_test(params.edge_band_px, labels) if labels is not None and overlap > 0 \
        else None
    same = same_part_test(params.same_part_share, estimator, jobs) if overlap > 0 else None
    return fragment_filter(jobs, publish, pose_stage(estimator).database, overlap,
                           explainer(params, estimator, jobs), joins, touching, band, same)


def explainer(params: FitParams, estimator: PoseEstimator | None, jobs: Sequence[PartJob]
              ) -> Callable[[Detection, Detection], bool] | None:
    """``explains(a, b)`` for the fragment filter: whether ``a``'s fitted part explains both
    its own and ``b``'s depth points (see the module); None when the unknown rule is off
    (either threshold 0) or there is no estimator. Answers are cached (one frame)."""
    if estimator is None or params.unknown_below_fitness <= 0 or \
            params.unknown_below_cover <= 0 or params.verify_inlier_m <= 0:
        return None
    by_detection = {id(job.detection): job for job in jobs}
    cache: dict[tuple[int, int], bool] = {}

    def passes(fitted: PartJob, points: np.ndarray) -> bool:
        detection = fitted.detection
        if detection.pose is None or detection.obj_id == UNKNOWN_ID or len(points) == 0:
            return False
        share, covered = outline_shares(params, points, detection.obj_id, detection.pose,
                                        estimator)
        return share >= params.unknown_below_fitness and covered >= params.unknown_below_cover

    def explains(a: Detection, b: Detection) -> bool:
        key = (id(a), id(b))
        if key not in cache:
            job_a, job_b = by_detection[id(a)], by_detection[id(b)]
            points = points_in_view(job_b, job_a)
            cache[key] = points is not None and passes(job_a, job_a.points) and \
                passes(job_a, points)
        return cache[key]
    return explains


def points_in_view(job: PartJob, other: PartJob) -> np.ndarray | None:
    """``job``'s ROI points in the optical frame of ``other``'s view (None: different views
    without both table frames)."""
    if job.detection.view == other.detection.view:
        return job.points
    if job.T_world_camera is None or other.T_world_camera is None:
        return None
    return transform_points(np.linalg.inv(other.T_world_camera) @ job.T_world_camera,
                            job.points)


def join_pieces(arbiter: FragmentFilter[Detection], detections: Sequence[Detection],
                labels: dict[str, np.ndarray]) -> list[Detection]:
    """``detections`` less the fragments ``arbiter`` dropped; each dropped piece that another
    detection's fit explains (``arbiter.kept_by``) joins it in every view of ``labels`` (its
    arrays are replaced, not written into), and that detection's box grows to the joined
    region in its view; a piece that is a neighbour's edge (``arbiter.erased``) is erased."""
    dropped = {id(d) for d in arbiter.dropped}
    joined: list[Detection] = []
    for piece in arbiter.dropped:
        if id(piece) in arbiter.erased:
            labels.update(without_label(labels, piece.instance_id))
            continue
        keeper = arbiter.kept_by.get(id(piece))
        seen = {id(piece)}
        while keeper is not None and id(keeper) in dropped and id(keeper) not in seen:
            seen.add(id(keeper))   # a piece of a piece
            keeper = arbiter.kept_by.get(id(keeper))
        if keeper is None or id(keeper) in dropped:
            continue
        for view, image in labels.items():
            where = image == piece.instance_id
            if where.any():
                labels[view] = np.where(where, keeper.instance_id, image).astype(image.dtype)
        joined.append(keeper)
    for keeper in joined:
        if keeper.view in labels:
            keeper.box = mask_box(labels[keeper.view] == keeper.instance_id)
    return [d for d in detections if id(d) not in dropped]


__all__ = ['explainer', 'join_pieces', 'one_part_filter', 'points_in_view']


def fitted_centre(estimator: PoseEstimator | None, job: PartJob
                  ) -> tuple[np.ndarray | None, float, float]:
    """A fitted part's centre in its fragment-filter frame, its class's diameter and its
    pose fitness (of two overlapping fits the one that explains more of its own ROI wins:
    the coverage term of the pose score favours a fragment fitted as the whole part)."""
    detection = job.detection
    if detection.pose is None:
        return None, 0.0, -np.inf
    centre = detection.pose.T_camera_object[:3, 3]
    if job.T_world_camera is not None:
        centre = transform_points(job.T_world_camera, centre[None])[0]
    return (centre, pose_stage(estimator).database[detection.obj_id].diameter_m,
            detection.pose.fitness)
