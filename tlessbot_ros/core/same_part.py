"""Two fits of one class that fill the same space are one part, fitted twice.

Where the localiser cuts one part into two touching regions, each region can be fitted as
the whole part placed over its own half. The two fitted models then fill much of the same
space, yet their centres may lie too far apart for the fragment filter's centre test, and
neither fit explains the other's points when each covers only its half. Two rigid parts
cannot fill the same space, so two fits of one class that do are the same part: the worse one
is a fragment of the better, and its region joins it (one part, one region, one box).

How much of the space two posed models share is read on the models' surface samples: a
sample of one lies in the other when it is inside it (behind its nearest surface sample, by
that sample's outward normal), or on its surface with the same outward direction (the same
face of two fits of a flat part a few millimetres thick, which has hardly an inside). Two
parts stacked face to face touch with opposite normals and share nothing; two parts side by
side share a sliver.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from scipy.spatial import cKDTree

from tlessbot_ros.core.common import transform_points
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.part_fit import pose_stage
from tlessbot_ros.core.pose import PoseEstimator, TemplateDatabase
from tlessbot_ros.core.recognise import UNKNOWN_ID

# A sample on the other model's surface (within this many sample spacings of its nearest
# sample) counts as shared only when the two outward normals agree this well (cosine).
_ON_SURFACE_SPACINGS = 1.5
_SAME_FACING = 0.5


def shared_share(points_a: np.ndarray, normals_a: np.ndarray, points_b: np.ndarray,
                 normals_b: np.ndarray, spacing_m: float) -> float:
    """The share of model A's surface samples that lie in model B (see the module).

    Args:
        points_a, normals_a: (N, 3) A's posed surface samples and outward unit normals, m.
        points_b, normals_b: (M, 3) B's, in the same frame.
        spacing_m: the samples' spacing (the larger of the two models'), m.

    Returns: a share in 0..1 (0 when either model has no samples).
    """
    if len(points_a) == 0 or len(points_b) == 0:
        return 0.0
    distance, nearest = cKDTree(points_b).query(points_a)
    offset = np.einsum('ij,ij->i', points_a - points_b[nearest], normals_b[nearest])
    on_surface = distance <= _ON_SURFACE_SPACINGS * spacing_m
    same_facing = np.einsum('ij,ij->i', normals_a, normals_b[nearest]) >= _SAME_FACING
    inside = (offset < 0) & ~on_surface
    return float(np.count_nonzero(inside | (on_surface & same_facing)) / len(points_a))


def posed_samples(database: TemplateDatabase, job: PartJob
                  ) -> tuple[np.ndarray, np.ndarray] | None:
    """A fitted job's model samples and normals in its fragment-filter frame (the world where
    it has a table frame, else its camera), or None: no pose or no known class."""
    detection = job.detection
    if detection.pose is None or detection.obj_id == UNKNOWN_ID or \
            detection.obj_id not in database:
        return None
    obj = database[detection.obj_id]
    T = detection.pose.T_camera_object
    if job.T_world_camera is not None:
        T = job.T_world_camera @ T
    model_normals, model_points = obj.model_arrays_float64()
    points = transform_points(T, model_points)
    normals = model_normals @ T[:3, :3].T
    return points, normals


def shared_shares(database: TemplateDatabase, job_a: PartJob, job_b: PartJob
                  ) -> tuple[float, float] | None:
    """(a's share in b, b's share in a) of two fitted jobs' model surfaces
    (:func:`shared_share`, at the coarser of their sample spacings), or None where either has
    no pose or no known class."""
    posed_a, posed_b = posed_samples(database, job_a), posed_samples(database, job_b)
    if posed_a is None or posed_b is None:
        return None
    spacing = max(database[job.detection.obj_id].sample_spacing_m() for job in (job_a, job_b))
    return (shared_share(*posed_a, *posed_b, spacing),
            shared_share(*posed_b, *posed_a, spacing))


def same_part_test(min_share: float, estimator: PoseEstimator | None,
                   jobs: Sequence[PartJob]) -> Callable[[Detection, Detection], bool] | None:
    """``same(a, b)`` for the fragment filter: ``a`` and ``b`` are fitted as one class, in
    one frame, and each model has at least ``min_share`` of its surface samples in the other
    (:func:`shared_share`); None when ``min_share`` is 0 or there is no estimator. Answers
    are cached (one frame)."""
    if min_share <= 0 or estimator is None:
        return None
    database = pose_stage(estimator).database
    by_detection = {id(job.detection): job for job in jobs}
    cache: dict[tuple[int, int], bool] = {}

    def same(a: Detection, b: Detection) -> bool:
        key = (min(id(a), id(b)), max(id(a), id(b)))
        if key in cache:
            return cache[key]
        job_a, job_b = by_detection.get(id(a)), by_detection.get(id(b))
        answer = False
        if job_a is not None and job_b is not None and a.obj_id == b.obj_id and \
                (job_a.T_world_camera is not None) == (job_b.T_world_camera is not None) and \
                (job_a.T_world_camera is not None or a.view == b.view):
            shares = shared_shares(database, job_a, job_b)
            answer = shares is not None and min(shares) >= min_share
        cache[key] = answer
        return answer
    return same


__all__ = ['posed_samples', 'same_part_test', 'shared_share', 'shared_shares']
