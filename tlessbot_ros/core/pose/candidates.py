"""What the pose paths return: refined candidates (:class:`PoseCandidate`) and the stage's
answer per object (:class:`PoseResult`)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

COVERAGE_WEIGHT = 0.3


@dataclass
class PoseCandidate:
    """One pose hypothesis after refinement.

    Attributes:
        T_camera_object: (4, 4) float64 pose in the ROI cloud's camera frame.
        fitness: fraction of scene points within ``inlier_voxels`` of the model surface.
        inlier_rmse_m: RMS point-to-model distance of those inliers, metres.
        coverage: fraction of the model surface facing the camera that has a scene point
            nearby (1 when unknown).
        method: 'table' or 'ransac'.
        template_index: the template a RANSAC candidate came from (-1 for the table path).
        stable_index: the stable pose of a table candidate (-1 otherwise).
        box_cover: in box mode, the share of the part's given box that the projected model
            covers (:func:`~tlessbot_ros.core.pose.image_box.box_cover`; 1 without a box).
    """

    T_camera_object: np.ndarray
    fitness: float
    inlier_rmse_m: float
    coverage: float = 1.0
    method: str = 'table'
    template_index: int = -1
    stable_index: int = -1
    box_cover: float = 1.0

    @property
    def score(self) -> float:
        """Ranking score: fitness, plus a weaker coverage term (the back-face visibility test
        behind coverage ignores self-occlusion, so it only breaks near-ties), times
        ``box_cover`` (a pose that leaves part of its box empty explains a neighbour)."""
        return (self.fitness + COVERAGE_WEIGHT * self.coverage) * self.box_cover

    @property
    def box_fitness(self) -> float:
        """``fitness`` times ``box_cover`` (the fitness itself without a box)."""
        return self.fitness * self.box_cover


@dataclass
class PoseResult:
    """Best and second-best candidates (paper: two templates) and per-stage times in ms.

    ``finalists``: the table path's ``final_candidates``, ranked, when its answer is the
    result (no fallback ran; empty otherwise), and ``polished`` whether they got the
    ``polish_iterations`` (:meth:`~tlessbot_ros.core.pose.PoseEstimator.polish`)."""

    obj_id: int
    best: PoseCandidate | None
    second: PoseCandidate | None
    n_points: int
    timings_ms: dict[str, float] = field(default_factory=dict)
    finalists: list[PoseCandidate] = field(default_factory=list)
    polished: bool = False


def poses_differ(T_a: np.ndarray, T_b: np.ndarray, *, t_m: float = 0.01, r_deg: float = 5.0
                 ) -> bool:
    """True when two (4, 4) poses differ by more than ``t_m`` metres or ``r_deg`` degrees."""
    cos = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1.0) / 2.0
    return bool(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) > t_m or
                np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) > r_deg)
