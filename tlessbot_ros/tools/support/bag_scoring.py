"""Scoring poses published by the graph against a bag's ground truth (demo, e2e, evaluate)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from tlessbot_ros.core.common import Rig, Symmetries, transform_points
from tlessbot_ros.core.metrics import PoseError, count_duplicates, is_correct_cm_deg, pose_error
from tlessbot_ros.io.ground_truth import GroundTruthInstance

MIN_VISIB_FRACT = 0.3


@dataclass
class Estimate:
    """A pose the graph published: source stamp, class, pose in ``frame_id``."""

    stamp_ns: int
    obj_id: int
    T: np.ndarray
    frame_id: str


@dataclass
class Match:
    """One ground-truth part of a frame and the estimate assigned to it (if any)."""

    truth: GroundTruthInstance
    estimate: Estimate | None
    error: PoseError | None

    @property
    def correct(self) -> bool:
        return self.error is not None and is_correct_cm_deg(self.error)


def score_frame(truth: Sequence[GroundTruthInstance], estimates: Sequence[Estimate],
                symmetries: dict[int, Symmetries], *,
                min_visib_fract: float = MIN_VISIB_FRACT) -> tuple[list[Match], list[Estimate]]:
    """Match one frame's estimates to its parts (same class; smallest rotation error first).

    Only parts at least ``min_visib_fract`` visible in some view are scored. Returns the
    matches (one per scored part) and the unmatched estimates (false positives; estimates of
    parts below the visibility bar are neither).
    """
    pairs = []
    for t_index, part in enumerate(truth):
        for e_index, estimate in enumerate(estimates):
            T_gt = part.T_camera_object.get(estimate.frame_id)
            if estimate.obj_id != part.obj_id or T_gt is None:
                continue
            error = pose_error(estimate.T, T_gt, symmetries.get(part.obj_id))
            pairs.append((error.ranking, t_index, e_index, error))
    pairs.sort(key=lambda p: p[0])
    used_truth: dict[int, tuple[int, PoseError]] = {}
    used_estimates: set[int] = set()
    for _, t_index, e_index, error in pairs:
        if t_index in used_truth or e_index in used_estimates:
            continue
        used_truth[t_index] = (e_index, error)
        used_estimates.add(e_index)
    matches = []
    ignored = set()
    for t_index, part in enumerate(truth):
        assigned = used_truth.get(t_index)
        if part.max_visib_fract < min_visib_fract:
            if assigned is not None:
                ignored.add(assigned[0])
            continue
        matches.append(Match(part, None if assigned is None else estimates[assigned[0]],
                             None if assigned is None else assigned[1]))
    false_positives = [e for i, e in enumerate(estimates)
                       if i not in used_estimates and i not in ignored]
    return matches, false_positives


def frame_duplicates(estimates: Sequence[Estimate], rig: Rig) -> int:
    """Poses of one frame that repeat another
    (:func:`~tlessbot_ros.core.metrics.count_duplicates`), each taken into the world frame
    through the rig of its ``frame_id`` (an optical frame of the rig or its world frame)."""
    frames = {cam.optical_frame: cam.T_world_camera for cam in rig.cameras.values()}
    frames[rig.world_frame] = np.eye(4)
    positions = [transform_points(frames[e.frame_id], e.T[:3, 3][None])[0]
                 for e in estimates if e.frame_id in frames]
    return count_duplicates(np.asarray(positions).reshape(-1, 3))


@dataclass
class PoseSetComparison:
    """Poses of one run paired with another run's poses of the same frame and class."""

    errors: list[PoseError]    # one per pair, symmetry-aware
    unpaired_reference: int    # reference poses the other run did not publish
    unpaired_other: int        # poses of the other run the reference did not publish

    @property
    def within_5cm_5deg(self) -> int:
        return sum(is_correct_cm_deg(error) for error in self.errors)


def compare_pose_sets(reference: Sequence[Estimate], other: Sequence[Estimate],
                      symmetries: dict[int, Symmetries]) -> PoseSetComparison:
    """Pair every pose of ``other`` with the closest ``reference`` pose of the same source
    stamp, class and frame (each used once; smallest rotation error first), as
    :func:`score_frame` pairs estimates with ground truth."""
    groups: dict[tuple[int, int, str], tuple[list[Estimate], list[Estimate]]] = {}
    for index, poses in enumerate((reference, other)):
        for pose in poses:
            groups.setdefault((pose.stamp_ns, pose.obj_id, pose.frame_id), ([], []))[index] \
                .append(pose)
    errors: list[PoseError] = []
    paired = 0
    for refs, others in groups.values():
        pairs = sorted(((pose_error(o.T, r.T, symmetries.get(r.obj_id)), i, j)
                        for i, r in enumerate(refs) for j, o in enumerate(others)),
                       key=lambda p: p[0].rotation_deg + 1e3 * p[0].translation_m)
        used_refs: set[int] = set()
        used_others: set[int] = set()
        for error, i, j in pairs:
            if i not in used_refs and j not in used_others:
                used_refs.add(i)
                used_others.add(j)
                errors.append(error)
        paired += len(used_refs)
    return PoseSetComparison(errors, len(reference) - paired, len(other) - paired)
