"""The tuning options of the composed pipeline, one frozen dataclass per stage.

:class:`LocaliseParams` (stage 1, the localiser node), :class:`ClassifyParams` (stage 2, the
classifier node) and :class:`FitParams` (stage 3, the pose estimator node and its workers).
The options of the stages' own algorithms live with them (``SegmentationParams``,
``FusionParams``, ``PoseParams``). The nodes declare these fields as ROS parameters under
their own names (no prefix), with the ``Attributes:`` text as descriptions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from tlessbot_ros.core.common.table_plane import TABLE_PLANE_MODES
from tlessbot_ros.core.pose.flat_params import FlatParams
from tlessbot_ros.core.pose.resting import RestingParams
from tlessbot_ros.core.pose.turns import TurnParams


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise ValueError(message)


@dataclass(frozen=True)
class LocaliseParams:
    """Stage 1: segmentation of both views and their fusion.

    Attributes:
        parallel_views: segment the top view in a second thread while this one segments the side
            view (same labels, less time).
    """

    parallel_views: bool = True


@dataclass(frozen=True)
class ClassifyParams:
    """Stage 2: which instances are classified, and which classes go on to the pose stage (the
    measurements behind the defaults: docs/bench/parameter-notes.md).

    Attributes:
        min_instance_px: instances with fewer pixels in a view do not count as seen there, px (>=
            1).
        reject_margin: classifier margin (summed over the views) below which the class is 'unknown'
            (>= 0; 0: the model's own).
        class_candidates: classes per part handed to the pose stage, best first (1..4; 1: the
            classifier alone decides).
        top_view_verify_below_margin: a part read in the top view has its other classes fitted only
            below this margin, in model margins (>= 0; inf: always).
        fit_rank_below_margin: below this margin, in model margins, more parts are ranked by
            their template fit (>= 0; 0: off).
        fit_rank_max_candidates: parts fitted for an unsure part, the classifier's best first
            (>= 0; 0: all; a count, not time).

    ``top_view_verify_below_margin`` is in units of the model's median margin on its training
    crops (``LinearClassifier.margin_scale``): seen from straight above a part shows mostly one
    face, which the templates of many parts fit, so only its least sure top-view crops are
    verified by the pose fit; side-view parts are always verified. ``class_candidates`` is at
    most 4, the channels of a 16UC4 image. ``fit_rank_*``: recognition by fit
    (:mod:`tlessbot_ros.core.by_fit`); between the nodes at most 4 candidates travel.
    """

    min_instance_px: int = 60
    reject_margin: float = 0.0
    class_candidates: int = 3
    top_view_verify_below_margin: float = 0.25
    fit_rank_below_margin: float = 0.0
    fit_rank_max_candidates: int = 8

    def __post_init__(self) -> None:
        _check(self.min_instance_px >= 1, f'min_instance_px must be at least 1 pixel, got '
               f'{self.min_instance_px}')
        _check(self.reject_margin >= 0, f'reject_margin must be >= 0 (0: the model default), '
               f'got {self.reject_margin}')
        _check(1 <= self.class_candidates <= 4, f'class_candidates must be 1..4 (the channels '
               f'of a 16UC<k> image), got {self.class_candidates}')
        _check(self.top_view_verify_below_margin >= 0, 'top_view_verify_below_margin must be '
               f'>= 0 (inf: always verify), got {self.top_view_verify_below_margin}')
        _check(self.fit_rank_below_margin >= 0, 'fit_rank_below_margin must be >= 0 (0: off), '
               f'got {self.fit_rank_below_margin}')
        _check(self.fit_rank_max_candidates >= 0, 'fit_rank_max_candidates must be >= 0 '
               f'(0: all parts), got {self.fit_rank_max_candidates}')


@dataclass(frozen=True)
class FitParams:
    """Stage 3: the ROI cloud of each part and the verification of its class candidates (the
    measurements behind the defaults: docs/bench/parameter-notes.md).

    Attributes:
        min_roi_points: fewer valid depth points than this: the pose is not estimated (>= 1).
        table_clearance_m: in box mode, ROI points closer than this to the table plane are dropped,
            m (>= 0).
        table_clearance_noise: in box mode, the clearance drops to where the noise measured on the
            table reaches at each point's depth, where that is lower (smoothed depth).
        box_cover: in box mode, the fit's poses are weighed by the share of the part's box their
            projected model covers, and also placed on the box's centre.
        steep_angle_deg: ROI pixels whose depth slope turns more than this from the camera are
            dropped (depth ramps at edges, grazing views), deg (0..90; 0: off).
        verify_accept_fitness: the first class is kept without fitting the others when its pose
            fitness reaches this (0..1).
        verify_rmse_weight: classes are ranked by fitness - weight * inlier RMSE, 1/m (>= 0; 50: 1
            mm costs 0.05 fitness).
        verify_inlier_m: classes are compared at this one tolerance from the surface, m (> 0;
            0: each at its own voxel, the pose score).
        verify_overrule_margin: another class replaces the classifier's first only when it
            scores higher by more than this (>= 0).
        verify_points: the ROI points the classes are compared on, at most (>= 1).
        fallback_min_fitness: no pose fallback for a region that no class fits better than this
            fitness (0..1): no known part.
        lookalike_check: compare a part with its look-alike twin at the fitted pose on the measured
            depth; the better one names it.
        lookalike_tolerance_m: a pixel votes for one look-alike when it explains the depth better
            by more than this, m (>= 0).
        lookalike_min_z: the twin overturns the class only with a vote surplus above this many
            coin-toss deviations (>= 0; 0: any).
        lookalike_all_views: the part's pixels in the other cameras vote in the look-alike check
            too (needs the rig extrinsics).
        lookalike_refine: on per-pixel depth, twins left open at the fit vote again, each from
            the pose near it that explains the most depth pixels.
        lookalike_edge_min_z: look-alikes are first compared on the colour image's edges at the
            fitted pose; the winner needs a surplus above this many coin-toss deviations (0: off).
        lookalike_shut_holes: there, a twin's through hole that the image shows as its face
            (``flat.edge_hole_contrast``) votes against that twin.
        fragment_overlap: a detection centred within this fraction of a larger one's diameter is
            its fragment: dropped (0..1; 0: off).
        table_plane: the table frame heights are read in: 'rig' (extrinsics), 'observed' (plane in
            each depth) or 'auto' (rig while it agrees).
        table_plane_max_angle_deg, table_plane_max_offset_m: in 'auto', the rig's table is kept
            while the observed plane is within this angle, deg, and height, m.
        fit_rank_min_fitness: a part whose candidates (more than one) all fit below this is
            reported unknown, without a pose (0..1; 0: off).
        unknown_below_fitness: a part whose fit explains less than this share of its depth
            points (within ``verify_inlier_m``) is reported unknown, no pose (0..1; 0: off).
        unknown_in_outline: that share is read on the points inside the fitted model's outline
            (neighbours in the region do not count against it); off: on all the region's points.
        unknown_below_cover: a part whose fitted outline covers less than this share of its
            mask's depth points is unknown (0..1; 0: off; never in box mode: a box holds others).
        unknown_without_fit: a part with depth but no fit (fewer than ``min_roi_points``
            points) is unknown too (off: it keeps the classifier's name).
        join_refit_cover: two touching pieces neither fit explains are one part when one fit
            of both covers this share of each one's points, and they of its outline (0: off).
        join_refit_gap_px: pieces of one view at most this many pixels apart touch (>= 0).
        join_refit_touching: touching pieces are neighbours whatever their centroids' distance,
            and a piece with no pose (unknown) is joined too (off: fitted neighbours only).
        trim_to_fit_px: a fitted part's region keeps only its pixels within this many pixels
            of the fitted outline, where it covers most of that outline (0: off).
        rim_colour_below: a region's outer pixel whose colour lies less than this share of the
            way from the colour beside it to the region's own is dropped (0..1; 0: off).
        edge_band_px: a region whose every pixel lies within this many pixels of a larger
            fitted part's region is that part's blurred edge: dropped, px (0: off).
        same_part_share: two fits of one class each this share inside the other are one part:
            the worse joins the better (0..1; 0: off).
        split_unexplained: a connected piece of a region's depth points (at least
            ``min_roi_points``) that its fit leaves unexplained is fitted as a part of its own.
        split_thick_parts: that division also where neither side is a flat part (off: only
            where one is; thick parts are left to the depth's seams).
        split_refit_below: a region whose fit explains less than this share of its depth points
            is fitted again on each half, and the better half's fit divides it (0..1; 0: off).
        fit_rank_coverage_weight: candidates also gain this times their coverage of the model's
            visible surface, but against their look-alike twin (>= 0; 0: off).
        flat: flat parts: the face that is up (depth and colour image), the yaw and a look-alike
            (image) (:class:`~tlessbot_ros.core.pose.FlatParams`).
        turns: parts that are not flat: a near-symmetric turn of the fit that the colour image
            shows better (:class:`~tlessbot_ros.core.pose.TurnParams`).

    ``table_plane``: 'rig' reads heights in the extrinsics alone (no table frame without them:
    every part goes to RANSAC); 'observed' uses the plane found in each view's depth
    (:mod:`tlessbot_ros.core.common.table_plane`, the rig's frame turned onto it); 'auto' the
    rig while the observed plane agrees with it, else the observed plane (and without
    extrinsics). The look-alike check ray-casts both meshes at the fitted pose along the ROI
    pixels (:class:`~tlessbot_ros.core.pose.LookalikeCheck`), with a sign test
    (:func:`~tlessbot_ros.core.pose.lookalike.clear_margin`). A fragment
    (``fragment_overlap``) is a piece of a part the localiser split (``core/fragments.py``).
    """

    min_roi_points: int = 30
    table_clearance_m: float = 0.004
    table_clearance_noise: bool = False
    box_cover: bool = True
    steep_angle_deg: float = 0.0
    verify_accept_fitness: float = 0.9
    verify_rmse_weight: float = 50.0
    verify_inlier_m: float = 0.003
    verify_overrule_margin: float = 0.05
    verify_points: int = 1500
    fallback_min_fitness: float = 0.1
    lookalike_check: bool = True
    lookalike_tolerance_m: float = 0.002
    lookalike_min_z: float = 2.0
    lookalike_all_views: bool = True
    lookalike_refine: bool = True
    lookalike_edge_min_z: float = 3.0
    lookalike_shut_holes: bool = True
    fragment_overlap: float = 0.5
    table_plane: str = 'auto'
    table_plane_max_angle_deg: float = 0.1
    table_plane_max_offset_m: float = 0.001
    fit_rank_min_fitness: float = 0.0
    unknown_below_fitness: float = 0.5
    unknown_in_outline: bool = True
    unknown_below_cover: float = 0.5
    unknown_without_fit: bool = False
    split_unexplained: bool = True
    split_thick_parts: bool = False
    split_refit_below: float = 0.0
    join_refit_cover: float = 0.8
    join_refit_gap_px: int = 3
    join_refit_touching: bool = True
    trim_to_fit_px: int = 3
    rim_colour_below: float = 0.0
    edge_band_px: int = 6
    same_part_share: float = 0.3
    fit_rank_coverage_weight: float = 0.0
    flat: FlatParams = field(default_factory=FlatParams)
    turns: TurnParams = field(default_factory=TurnParams)
    resting: RestingParams = field(default_factory=RestingParams)

    def __post_init__(self) -> None:
        _check(self.min_roi_points >= 3, f'min_roi_points must be at least 3 (a pose needs '
               f'3 points), got {self.min_roi_points}')
        _check(self.table_clearance_m >= 0, f'table_clearance_m must be >= 0 m, got '
               f'{self.table_clearance_m}')
        _check(self.verify_accept_fitness >= 0, 'verify_accept_fitness must be >= 0 (a '
               f'fitness; above 1: always fit every candidate), got '
               f'{self.verify_accept_fitness}')
        _check(0 <= self.steep_angle_deg <= 90, 'steep_angle_deg must be in 0..90 (0: off), '
               f'got {self.steep_angle_deg}')
        _check(self.verify_inlier_m >= 0, 'verify_inlier_m must be >= 0 m (0: each class at its '
               f'own voxel), got {self.verify_inlier_m}')
        _check(self.verify_overrule_margin >= 0, 'verify_overrule_margin must be >= 0, got '
               f'{self.verify_overrule_margin}')
        _check(self.verify_points >= 1, f'verify_points must be >= 1, got {self.verify_points}')
        _check(self.verify_rmse_weight >= 0 and math.isfinite(self.verify_rmse_weight),
               f'verify_rmse_weight must be a finite value >= 0 (1/m), got '
               f'{self.verify_rmse_weight}')
        _check(0 <= self.fallback_min_fitness <= 1, 'fallback_min_fitness must be in 0..1 '
               f'(a fitness), got {self.fallback_min_fitness}')
        _check(0 <= self.fit_rank_min_fitness <= 1, 'fit_rank_min_fitness must be in 0..1 '
               f'(a fitness; 0: off), got {self.fit_rank_min_fitness}')
        _check(0 <= self.unknown_below_fitness <= 1, 'unknown_below_fitness must be in 0..1 '
               f'(a fitness; 0: off), got {self.unknown_below_fitness}')
        _check(0 <= self.unknown_below_cover <= 1, 'unknown_below_cover must be in 0..1 '
               f'(a share; 0: off), got {self.unknown_below_cover}')
        _check(0 <= self.join_refit_cover <= 1 and self.join_refit_gap_px >= 0,
               'join_refit_cover must be in 0..1 (a share; 0: off) and join_refit_gap_px >= 0, '
               f'got {self.join_refit_cover}, {self.join_refit_gap_px}')
        _check(self.edge_band_px >= 0, 'edge_band_px must be >= 0 (0: off), got '
               f'{self.edge_band_px}')
        _check(0 <= self.same_part_share <= 1, 'same_part_share must be in 0..1 (a share; '
               f'0: off), got {self.same_part_share}')
        _check(0 <= self.split_refit_below <= 1, 'split_refit_below must be in 0..1 (a share; '
               f'0: off), got {self.split_refit_below}')
        _check(self.trim_to_fit_px >= 0, 'trim_to_fit_px must be >= 0 (0: off), got '
               f'{self.trim_to_fit_px}')
        _check(0 <= self.rim_colour_below <= 1, 'rim_colour_below must be in 0..1 (a share; '
               f'0: off), got {self.rim_colour_below}')
        _check(self.fit_rank_coverage_weight >= 0, 'fit_rank_coverage_weight must be >= 0 '
               f'(0: off), got {self.fit_rank_coverage_weight}')
        _check(self.lookalike_tolerance_m > 0, 'lookalike_tolerance_m must be > 0 m (e.g. '
               f'0.002), got {self.lookalike_tolerance_m}')
        _check(self.lookalike_min_z >= 0 and math.isfinite(self.lookalike_min_z),
               'lookalike_min_z must be a finite value >= 0 (standard deviations; 0: any '
               f'surplus), got {self.lookalike_min_z}')
        _check(self.lookalike_edge_min_z >= 0 and math.isfinite(self.lookalike_edge_min_z),
               'lookalike_edge_min_z must be a finite value >= 0 (standard deviations; 0: off), '
               f'got {self.lookalike_edge_min_z}')
        _check(self.table_plane in TABLE_PLANE_MODES, f'table_plane must be one of '
               f'{", ".join(TABLE_PLANE_MODES)}, got {self.table_plane!r}')
        _check(self.table_plane_max_angle_deg >= 0 and self.table_plane_max_offset_m >= 0,
               'table_plane_max_angle_deg and table_plane_max_offset_m must be >= 0')
        _check(0.0 <= self.fragment_overlap < 1.0, 'fragment_overlap must be in [0, 1) (0.5; '
               f'0 turns the check off), got {self.fragment_overlap}')
