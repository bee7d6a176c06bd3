"""Settings of the pose stage (:class:`PoseParams`), shared by the estimator, its refinement
(:mod:`tlessbot_ros.core.pose.refinement`) and the RANSAC path
(:mod:`tlessbot_ros.core.pose.ransac`)."""
from __future__ import annotations

from dataclasses import dataclass, field

from tlessbot_ros.core.pose.cloud import CloudParams

METHODS = ('table', 'ransac')
FALLBACK_METHODS = ('views', 'templates')


@dataclass(frozen=True)
class PoseParams:
    """Pose-estimation parameters (voxel scales are multiples of the database voxel, which is a
    fraction of the object's diameter; the measurements behind the defaults:
    docs/bench/parameter-notes.md).

    Attributes:
        method: 'table' (fast path, with a fallback when its fit is poor or there is no table
            frame) or 'ransac' (the paper's FPFH + RANSAC against every template).
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
        polish_iterations: table path: more point-to-plane ICP steps for the final candidates on
            every ROI point (>= 0; 0: off).
        polish_distance_voxels: their correspondence distance (the first half at twice it).
        polish_margin_fitness: only finalists within this fitness of the winner before the polish
            are polished (0..1; 1: all).
        polish_overturn_fitness: after the polish, another finalist replaces the winner only when
            fitter by more than this (0..1; 1: by score).
        inlier_voxels: distance of a scene point to the model surface counted as an inlier.
        inlier_plane_m: an inlier must also lie this close to the tangent plane of its nearest
            model sample (0: off); used for the final ranking.
        fallback_fitness: the table path falls back below this fitness (0..1).
        fallback: run that fallback at all (off: the table path's best is returned).
        fallback_method: 'views' (bounded 6-DOF search over a grid of views, tens of ms a part) or
            'templates' (FPFH + RANSAC, seconds).
        force_fallback: send every part straight to the fallback, without trying the table path.
        fallback_templates: 'templates' fallback: the templates whose view is closest in
            rotation to the table path's best hypotheses, at most this many.
        fallback_max_iteration: 'templates' fallback: RANSAC iterations per template.
        fallback_budget_ms: wall-time cap on the fallback from the start of the estimate, ms
            (0: none, so results do not depend on the host's speed; > 0: stops early).
        fallback_directions: 'views': viewing directions spread over the sphere (300: about
            12° apart).
        fallback_in_plane_steps: 'views': turns about the line of sight per direction (24:
            15° apart); directions x steps views in all, fewer for symmetric parts.
        fallback_voxel_scale: 'views': the ROI is scored on a grid this much coarser than the
            template voxel.
        fallback_coarse_points: 'views': every view is scored on this many coarse ROI points,
            the best ``fallback_keep`` again on ``score_points``.
        fallback_keep: 'views': the best this many views are scored again on ``score_points``
            (>= 1).
        fallback_icp_starts: 'views': the best this many views get ICP on the coarse points (>= 1).
        fallback_icp_iterations: 'views': ICP steps of each of those starts (>= 1).
        fallback_icp_distance_voxels: 'views': their correspondence distance, template voxels
            (> 0).
        fallback_refine: 'views': the best distinct coarse poses refined at the template
            voxel (``icp_iterations``).
        fallback_turned: 'views': the best this many of those are turned by each of the part's
            near-symmetries and refined again.
        fallback_fine_iterations: 'views': the final ICP steps of the ``final_candidates``
            survivors, with every ROI point.
        fallback_drop_planes: 'views': remove up to this many wide planes (the table) from the ROI
            first (>= 0; 0: off).
        fallback_plane_width: 'views': only planes wider than this many part diameters are
            removed (> 0).
        fallback_table_band: 'views' with a table frame: drop the points this many
            plane_distance_m near or below the table, not a searched plane (>= 0; 0: off).
        ransac_distance_voxels: SAC-IA: inlier distance of the RANSAC registration, template
            voxels.
        ransac_edge_length: SAC-IA: edge-length similarity of the correspondence check (0..1).
        ransac_mutual_filter: SAC-IA: keep only mutual FPFH correspondences.
        ransac_max_iteration: SAC-IA: most RANSAC iterations per template (>= 1).
        ransac_confidence: SAC-IA: confidence at which RANSAC stops early (0..1).
        fpfh_radius_voxels, fpfh_max_nn: scene FPFH support (as in the templates).
        refine: refine RANSAC candidates with ICP (off = the paper's plain pipeline).
        ransac_candidates: RANSAC candidates (best by raw fitness) that get refined.
        seed: seeds the hypothesis subset and Open3D's RANSAC.

    The polish (``polish_iterations``): the short ICP of the many starts stops a few degrees short
    on noisy depth, so a pose turned by ~180° could rank as high as the right one. In the class
    verification (``PerceptionPipeline.fit_part``) the candidate classes are compared unpolished
    and only the winner's finalists are polished
    (:meth:`~tlessbot_ros.core.pose.PoseEstimator.polish`): polishing every class lets wrong
    ones converge too, and the score's coverage term (blind to self-occlusion) favours some
    poses turned by ~180°, hence ``polish_overturn_fitness``
    (:func:`~tlessbot_ros.core.pose.estimator.after_polish`). The 'views' fallback is the
    bounded search of :mod:`tlessbot_ros.core.pose.fallback` (a grid of views scored on the
    model's nearest-sample grid, ICP at the template voxel, the near-symmetry turns); it is
    also used without a table frame. A view's position comes from surface centroids, which
    occlusion shifts by a few voxels, so its first ICP steps use twice
    ``fallback_icp_distance_voxels``. ``fallback_drop_planes`` removes RANSAC planes
    (``cloud.plane_distance_m``) wider than ``fallback_plane_width`` times the part's diameter
    (no face of a part is wider): the table in a box ROI without a table frame. With a table
    frame the first of them is the table itself, known rather than searched: the points within
    ``fallback_table_band`` times ``cloud.plane_distance_m`` of it, or below it, leave the ROI
    where they spread wider than ``fallback_plane_width`` diameters (a plane searched by RANSAC
    may be a near-equal neighbour of the table's, and which one is found turns the pose). The
    ``ransac_*`` settings are SAC-IA's (algo-notes §C.4).
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
    polish_iterations: int = 30
    polish_distance_voxels: float = 1.0
    polish_margin_fitness: float = 0.2
    polish_overturn_fitness: float = 0.01
    inlier_voxels: float = 1.0
    inlier_plane_m: float = 0.0025
    fallback_fitness: float = 0.85
    fallback: bool = True
    fallback_templates: int = 3
    fallback_max_iteration: int = 5000
    fallback_budget_ms: float = 0.0
    fallback_method: str = 'views'
    force_fallback: bool = False
    fallback_directions: int = 300
    fallback_in_plane_steps: int = 24
    fallback_voxel_scale: float = 1.5
    fallback_coarse_points: int = 60
    fallback_keep: int = 200
    fallback_icp_starts: int = 30
    fallback_icp_iterations: int = 6
    fallback_icp_distance_voxels: float = 3.0
    fallback_refine: int = 4
    fallback_turned: int = 2
    fallback_fine_iterations: int = 16
    fallback_drop_planes: int = 1
    fallback_plane_width: float = 1.0
    fallback_table_band: float = 0.0
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
        if self.fallback_method not in FALLBACK_METHODS:
            raise ValueError(f'fallback_method must be one of {FALLBACK_METHODS}, got '
                             f'{self.fallback_method!r}')
        if min(self.fallback_directions, self.fallback_in_plane_steps, self.fallback_keep,
               self.fallback_icp_starts, self.fallback_refine) < 1:
            raise ValueError('fallback_directions, fallback_in_plane_steps, fallback_keep, '
                             'fallback_icp_starts and fallback_refine must be >= 1')
        if self.fallback_coarse_points < 10 or min(self.fallback_icp_iterations,
                                                   self.fallback_fine_iterations,
                                                   self.fallback_turned) < 0:
            raise ValueError('fallback_coarse_points must be >= 10; fallback_icp_iterations, '
                             'fallback_fine_iterations and fallback_turned >= 0')
        if self.fallback_table_band < 0:
            raise ValueError('fallback_table_band must be >= 0 (0: search the table as any '
                             f'plane; 1: one plane_distance_m), got {self.fallback_table_band}')
        if self.fallback_drop_planes < 0 or self.fallback_plane_width <= 0:
            raise ValueError('fallback_drop_planes must be >= 0 and fallback_plane_width > 0 '
                             f'(1: the part diameter), got {self.fallback_drop_planes}, '
                             f'{self.fallback_plane_width}')
        if self.polish_iterations < 0 or self.polish_distance_voxels <= 0:
            raise ValueError('polish_iterations must be >= 0 (0: off) and '
                             'polish_distance_voxels > 0 (1: one voxel), got '
                             f'{self.polish_iterations}, {self.polish_distance_voxels}')
        if self.polish_margin_fitness < 0:
            raise ValueError('polish_margin_fitness must be >= 0 (a fitness difference; 1: '
                             f'polish every finalist), got {self.polish_margin_fitness}')
        if self.polish_overturn_fitness < 0:
            raise ValueError('polish_overturn_fitness must be >= 0 (a fitness difference; 1: '
                             f'rank by score), got {self.polish_overturn_fitness}')
        if self.fallback_budget_ms < 0:
            raise ValueError('fallback_budget_ms must be >= 0 (0: no wall-time cap), got '
                             f'{self.fallback_budget_ms}')
        if self.fallback_icp_distance_voxels <= 0:
            raise ValueError('fallback_icp_distance_voxels must be > 0 (3: three voxels), got '
                             f'{self.fallback_icp_distance_voxels}')
        if self.fallback_voxel_scale <= 0:
            raise ValueError(f'fallback_voxel_scale must be > 0 (1.5: a coarser grid than the '
                             f'templates), got {self.fallback_voxel_scale}')
