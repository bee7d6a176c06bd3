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
    fraction of the object's diameter).

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
        polish_iterations: table path: the ``final_candidates`` get this many more
            point-to-plane ICP steps on every ROI point before the answer is taken (0: off).
            The short ICP of the many starts stops a few degrees short on noisy depth, so a
            pose turned by ~180° ranked as high as the right one. In the class verification
            (``PerceptionPipeline.fit_part``) the candidate classes are compared unpolished
            and only the winner's finalists are polished
            (:meth:`~tlessbot_ros.core.pose.PoseEstimator.polish`): polishing every class let
            wrong ones converge too. 30: on 12 simulated scenes (6 moved rigs, 6 exact) 319 ->
            327 of 356 parts within 5 cm / 5° on the moved rigs, 325 -> 329 on the exact
            ones, the demo bag stays at 26 of 27; about +25 % pose-stage CPU per frame
            (docs/bench/moved-rig-accuracy.md, session 12), about half of that since session
            13 (a faster ICP kernel, per-pose stopping, ``polish_margin_fitness``).
        polish_distance_voxels: their correspondence distance (the first half at twice it).
        polish_margin_fitness: only the finalists whose fitness before the polish is within
            this of the former winner's are polished (the winner always); the others keep
            their fit and rank after it. 0.2: on 12 simulated scenes (741 polished parts)
            the finalists that the polish made winners had been at most 0.13 behind (62 of 65
            within 0.06), and 14 % of the finalists' ICP and scoring is saved
            (docs/bench/moved-rig-accuracy.md, session 13). 1: polish all.
        polish_overturn_fitness: after the polish, another finalist replaces the former
            winner only when its fitness (a fraction of the ROI points) is higher by more than
            this (:func:`~tlessbot_ros.core.pose.estimator.after_polish`): the polish lets
            wrong finalists converge too, and the score's coverage term (blind to
            self-occlusion) favours some poses turned by ~180°. 1: rank them by score.
        inlier_voxels: distance of a scene point to the model surface counted as an inlier.
        inlier_plane_m: an inlier must also lie this close to the tangent plane of its nearest
            model sample (0: off); used for the final ranking.
        fallback_fitness: the table path falls back below this fitness. 0.85 rather than
            0.7 since the fallback is cheap: a part leaning on another often gets a wrong
            table pose with fitness 0.7-0.85 (on 65 leaning simulated parts 0.74 right at
            5 cm / 5° with 0.7, 0.95 with 0.85), while 4 % of resting parts go to the fallback
            (docs/bench/fallback.md).
        fallback: run that fallback at all (off: the table path's best is returned).
        fallback_method: 'views' (default) the bounded 6-DOF search of
            :mod:`tlessbot_ros.core.pose.fallback`: a grid of views scored on the model's
            nearest-sample grid, ICP at the template voxel, the near-symmetry turns, ~20-40 ms
            a part; 'templates' the former fallback: FPFH + RANSAC against the templates
            nearest the table path's best (all of them, ``ransac_max_iteration`` each, without
            a table frame: 1-3 s a part). Also used without a table frame.
        force_fallback: send every part straight to the fallback, without trying the table
            path (parts known to lean or lie on others; benchmarks).
        fallback_templates: 'templates' fallback: the templates whose view is closest in
            rotation to the table path's best hypotheses, at most this many.
        fallback_max_iteration: 'templates' fallback: RANSAC iterations per template.
        fallback_budget_ms: a safety net, in ms since
            :meth:`~tlessbot_ros.core.pose.PoseEstimator.estimate` began: once spent, the
            'views' fallback skips its near-symmetry turns and the 'templates' fallback starts
            no further template.
        fallback_directions: 'views': viewing directions spread over the sphere (300: about
            12° apart).
        fallback_in_plane_steps: 'views': turns about the line of sight per direction (24:
            15° apart); directions x steps views in all, fewer for symmetric parts.
        fallback_voxel_scale: 'views': the ROI is scored on a grid this much coarser than the
            template voxel.
        fallback_coarse_points: 'views': every view is scored on this many coarse ROI points,
            the best ``fallback_keep`` again on ``score_points``.
        fallback_keep: see ``fallback_coarse_points``.
        fallback_icp_starts: 'views': the best this many views get ``fallback_icp_iterations``
            point-to-plane ICP steps on the coarse points, correspondences within
            ``fallback_icp_distance_voxels`` voxels (twice that in the first half: a view's
            position comes from surface centroids, which occlusion shifts by a few voxels).
        fallback_icp_iterations, fallback_icp_distance_voxels: see ``fallback_icp_starts``.
        fallback_refine: 'views': the best distinct coarse poses refined at the template
            voxel (``icp_iterations``).
        fallback_turned: 'views': the best this many of those are turned by each of the part's
            near-symmetries and refined again.
        fallback_fine_iterations: 'views': the final ICP steps of the ``final_candidates``
            survivors, with every ROI point.
        fallback_drop_planes: 'views': first remove up to this many RANSAC planes
            (``cloud.plane_distance_m``) wider than ``fallback_plane_width`` times the part's
            diameter from the ROI: the table in a box ROI without a table frame (one view,
            no plane found: 0.74 -> 0.88 at 5 cm / 5° on 119 simulated parts). No face of the
            part is wider than its diameter. 0: off.
        fallback_plane_width: see ``fallback_drop_planes``.
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
    fallback_budget_ms: float = 100.0
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
        if self.fallback_icp_distance_voxels <= 0:
            raise ValueError('fallback_icp_distance_voxels must be > 0 (3: three voxels), got '
                             f'{self.fallback_icp_distance_voxels}')
        if self.fallback_voxel_scale <= 0:
            raise ValueError(f'fallback_voxel_scale must be > 0 (1.5: a coarser grid than the '
                             f'templates), got {self.fallback_voxel_scale}')
