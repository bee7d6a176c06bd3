"""Settings of the pose stage (:class:`PoseParams`), shared by the estimator, its refinement
(:mod:`tlessbot_ros.core.pose.refinement`) and the RANSAC path
(:mod:`tlessbot_ros.core.pose.ransac`)."""
from __future__ import annotations

from dataclasses import dataclass, field

from tlessbot_ros.core.pose.cloud import CloudParams

METHODS = ('table', 'ransac')


@dataclass(frozen=True)
class PoseParams:
    """Pose-estimation parameters (voxel scales are multiples of the database voxel, which is a
    fraction of the object's diameter).

    Attributes:
        method: 'table' (fast path, RANSAC fallback) or 'ransac'.
        yaw_step_deg: yaw hypothesis spacing of the table path.
        max_stable_poses: stable poses searched (most probable first).
        min_stable_probability: less likely stable poses are skipped.
        table_voxel_scale: the table path voxelises the ROI this much coarser than the
            templates (fewer points; the CAD surface is matched, not FPFH features).
        score_points: scene points used to score hypotheses (random, seeded subset).
        top_k: hypotheses refined in (yaw, x, y).
        flip_hypotheses: the best this many also enter turned by 180° in yaw.
        flip_axes: also refine the best turned by 180° about each object axis (through the
            surface centroid) and keep whichever fits best.
        final_candidates: refined table candidates scored fully (fitness and coverage).
        planar_iterations: Gauss-Newton steps of that refinement.
        icp_iterations: final 6-DOF point-to-plane ICP iterations.
        icp_distance_voxels: ICP correspondence distance (final iterations; the first ones
            start at twice this).
        icp_points: ICP uses at most this many scene points (evenly strided).
        inlier_voxels: distance of a scene point to the model surface counted as an inlier.
        inlier_plane_m: an inlier must also lie this close to the tangent plane of its nearest
            model sample (0: off); used for the final ranking.
        fallback_fitness: the table path falls back to RANSAC below this fitness.
        fallback: run that fallback at all (off: the table path's best is returned).
        fallback_templates: the fallback registers only the templates whose view is closest
            in rotation to the table path's best hypotheses, at most this many.
        fallback_max_iteration: RANSAC iterations per template in the fallback.
        fallback_budget_ms: the fallback starts no further template once this much time has
            passed since :meth:`~tlessbot_ros.core.pose.PoseEstimator.estimate`
            began (bounds the worst case).
        ransac_distance_voxels, ransac_edge_length, ransac_mutual_filter,
        ransac_max_iteration, ransac_confidence: the SAC-IA settings (algo-notes §C.4).
        fpfh_radius_voxels, fpfh_max_nn: scene FPFH support (as in the templates).
        refine: refine RANSAC candidates with ICP (off = the paper's plain pipeline).
        ransac_candidates: RANSAC candidates (best by raw fitness) that get refined.
        seed: seeds the hypothesis subset and Open3D's RANSAC.
    """

    method: str = 'table'
    yaw_step_deg: float = 15.0
    max_stable_poses: int = 8
    min_stable_probability: float = 0.02
    table_voxel_scale: float = 1.5
    score_points: int = 200
    top_k: int = 6
    flip_hypotheses: int = 2
    flip_axes: bool = True
    final_candidates: int = 3
    planar_iterations: int = 6
    icp_iterations: int = 8
    icp_distance_voxels: float = 1.5
    icp_points: int = 250
    inlier_voxels: float = 1.0
    inlier_plane_m: float = 0.0025
    fallback_fitness: float = 0.7
    fallback: bool = True
    fallback_templates: int = 3
    fallback_max_iteration: int = 5000
    fallback_budget_ms: float = 60.0
    ransac_distance_voxels: float = 1.5
    ransac_edge_length: float = 0.9
    ransac_mutual_filter: bool = True
    ransac_max_iteration: int = 100000
    ransac_confidence: float = 0.999
    fpfh_radius_voxels: float = 5.0
    fpfh_max_nn: int = 100
    refine: bool = True
    ransac_candidates: int = 3
    seed: int = 0
    cloud: CloudParams = field(default_factory=CloudParams)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f'method must be one of {METHODS}, got {self.method!r}')
        if not 0.0 < self.yaw_step_deg <= 180.0:
            raise ValueError(f'yaw_step_deg must be in (0, 180], got {self.yaw_step_deg}')
        if self.top_k < 1 or self.score_points < 10 or self.max_stable_poses < 1:
            raise ValueError('top_k and max_stable_poses must be >= 1, score_points >= 10')
