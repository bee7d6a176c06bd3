"""False parts that the scored camera does not see: poses whose centre projects outside the
scored (side) image and that lie near no ground-truth part.

``evaluate`` counts false positives among the scored view's boxes, so a part that only the
other camera found (a noise patch on the table beside the side image) is in none of its
figures, yet the graph publishes its pose. This is their count, kept apart from the
false-positive figure so that every bench's baseline stays comparable
(docs/bench/unseen-false-parts.md).
"""
from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from tlessbot_ros.core.common import project_points
from tlessbot_ros.io.bop_results import BopEstimate


def outside_image(image, t_camera_m: np.ndarray) -> bool:
    """Whether the point ``t_camera_m`` (3,) (the image's camera frame, metres) projects
    outside ``image`` (its intrinsics), or lies behind the camera."""
    u, v = project_points(np.asarray(t_camera_m, float), image.intrinsics.K)[0]
    return not (np.isfinite(u) and 0 <= u < image.intrinsics.width
                and 0 <= v < image.intrinsics.height)


def near_a_part(image, t_camera_m: np.ndarray, radius_m: Callable[[int], float]) -> bool:
    """Whether ``t_camera_m`` lies within ``radius_m(obj_id)`` of the centre of one of the
    image's ground-truth parts (any class, seen or not: a part hidden from this camera is
    still a part)."""
    t = np.asarray(t_camera_m, float)
    return any(np.linalg.norm(gt.T_camera_object[:3, 3] - t) <= radius_m(gt.obj_id)
               for gt in image.gt)


def unscored_false_parts(image, poses: Iterable[BopEstimate],
                         radius_m: Callable[[int], float]) -> int:
    """How many of ``poses`` (one frame, the image's camera frame) lie outside the image
    (:func:`outside_image`) and near no ground-truth part (:func:`near_a_part`;
    ``radius_m(obj_id)``: how far from a part's centre a pose of it may lie, e.g. half the
    part's diameter)."""
    return sum(outside_image(image, p.T_camera_object[:3, 3])
               and not near_a_part(image, p.T_camera_object[:3, 3], radius_m) for p in poses)


def unscored_false_parts_per_frame(frames: list, radius_m: Callable[[int], float]
                                   ) -> float | None:
    """:func:`unscored_false_parts` per frame over ``frames`` ((BopImage, FrameOutput)
    pairs), None where the pose stage ran on none of them."""
    if not any(output.pose_ran for _, output in frames):
        return None
    return sum(unscored_false_parts(image, output.poses, radius_m)
               for image, output in frames) / len(frames)


__all__ = ['near_a_part', 'outside_image', 'unscored_false_parts',
           'unscored_false_parts_per_frame']
