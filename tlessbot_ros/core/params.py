"""The tuning options of the composed pipeline, one frozen dataclass per stage.

:class:`LocaliseParams` (stage 1, the localiser node), :class:`ClassifyParams` (stage 2, the
classifier node) and :class:`FitParams` (stage 3, the pose estimator node and its workers).
The options of the stages' own algorithms live with them (``SegmentationParams``,
``FusionParams``, ``PoseParams``). The nodes declare these fields as ROS parameters under
their own names (no prefix), with the ``Attributes:`` text as descriptions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from tlessbot_ros.core.common.table_plane import TABLE_PLANE_MODES


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise ValueError(message)


@dataclass(frozen=True)
class LocaliseParams:
    """Stage 1: segmentation of both views and their fusion.

    Attributes:
        parallel_views: :meth:`PerceptionPipeline.localise` segments the top view in a second
            thread while this one segments the side view (OpenCV and most numpy calls release
            the GIL: 20.6 -> 16.4 ms per frame for both views on 2 cores, same labels).
    """

    parallel_views: bool = True


@dataclass(frozen=True)
class ClassifyParams:
    """Stage 2: which instances are classified, and which classes go on to the pose stage.

    Attributes:
        min_instance_px: instances with fewer pixels in a view do not count as seen there
            (not classified there, and their pose is not read there).
        reject_margin: classifier margin below which the class is 'unknown' (0 = the model's
            own); the margin is read on the scores summed over the views that see the part.
        class_candidates: classes per part handed to the pose stage, best first (1 = the
            classifier alone decides, as in the paper; at most 4, the channels of a 16UC4
            image).
        top_view_verify_below_margin: for a part whose pose is read in the top view (the side
            camera does not see it), the classifier's other candidates are fitted only when
            its margin (best minus second-best score, summed over the views) is below this
            many times its median margin on its training crops
            (``LinearClassifier.margin_scale``); above, its first class alone is fitted (and,
            if it has a look-alike, checked). Seen from straight above a part shows mostly
            one face, which the templates of many parts fit: verifying every top-view crop of
            2 × 300 simulated scenes (seeds 2024, 3030; the previous packaged model) names
            79-82 % of them right, against 93 % for the classifier alone, while its least
            sure 9 % (margin below 0.25 of the median) are right at 50-58 % and verified at
            70-81 %. Side-view parts are always verified (96 % against 93 %). ``inf``: always
            verify (also when the model file has no ``margin_scale``).
    """

    min_instance_px: int = 60
    reject_margin: float = 0.0
    class_candidates: int = 3
    top_view_verify_below_margin: float = 0.25

    def __post_init__(self) -> None:
        _check(self.min_instance_px >= 1, f'min_instance_px must be at least 1 pixel, got '
               f'{self.min_instance_px}')
        _check(self.reject_margin >= 0, f'reject_margin must be >= 0 (0: the model default), '
               f'got {self.reject_margin}')
        _check(1 <= self.class_candidates <= 4, f'class_candidates must be 1..4 (the channels '
               f'of a 16UC<k> image), got {self.class_candidates}')
        _check(self.top_view_verify_below_margin >= 0, 'top_view_verify_below_margin must be '
               f'>= 0 (inf: always verify), got {self.top_view_verify_below_margin}')


@dataclass(frozen=True)
class FitParams:
    """Stage 3: the ROI cloud of each part and the verification of its class candidates.

    Attributes:
        min_roi_points: fewer valid depth points than this: the pose is not estimated.
        table_clearance_m: in box mode, ROI points closer than this to the table plane are
            dropped (the box holds table pixels around the part).
        verify_accept_fitness: the first candidate is kept without fitting the others when its
            pose fitness reaches this. 0.9 rather than 0.95: on 542 simulated parts (ground-
            truth masks, seed 1000) 1.23 instead of 1.49 fits per part, 7.2 instead of 8.8 ms,
            93.2 against 93.4 % right (one part); evaluate on sim50 0.901 against 0.905 at
            5 cm/5° (one part of 222); in paired 60 s ``bench graph`` runs p95 133-145 against
            141-156 ms.
        verify_rmse_weight: candidates are ranked by fitness - weight * inlier RMSE (1/m), so
            1 mm of RMSE costs 0.05 of fitness.
        fallback_min_fitness: after verification, the pose fallback is not tried for a
            region that no candidate fits at all (best fitness below this): such a region is
            no known part on the table (an arm, a shadow) and the fallback would spend its
            whole budget on it.
        lookalike_check: after the fit, a part whose class has a look-alike in the template
            database is compared with it: both meshes are ray-cast at the fitted pose along
            the ROI pixels, and the one that explains more of the measured depth names the
            part (:class:`~tlessbot_ros.core.pose.LookalikeCheck`).
        lookalike_tolerance_m: a pixel votes for one look-alike when it explains the depth
            better by more than this (metres).
        lookalike_min_z: the look-alike overturns the fitted class only when its surplus of
            votes is more than this many standard deviations of a coin toss over the pixels
            that vote (a sign test, :func:`~tlessbot_ros.core.pose.lookalike.clear_margin`);
            0: on any surplus (before session 13). On the 12 two-view scenes of
            docs/bench/lookalike-twins.md the wrong overturns were decided by 1-3 pixels of
            about 3000 (features facing the table), the right ones by 21-473 but one (2).
        lookalike_all_views: the pixels of the part in the other cameras (rig extrinsics,
            at least ``min_instance_px`` there) vote too, at the fitted pose carried into
            those cameras (about +2 ms a twin). On those 12 scenes it changed one decision
            (a part whose pose was turned anyway): a feature the side camera cannot see
            faces the table, out of the top camera's sight too.
        fragment_overlap: two rigid parts cannot sit inside each other: a detection whose
            fitted centre lies closer than this fraction of the smaller part's diameter to the
            centre of a detection with more ROI points is a fragment of that part (the
            localiser split it) and is dropped, not published (``core/fragments.py``). Every
            duplicate pose in 3 simulated 15-frame bags was such a fragment (the pieces' fits
            lay 0.3-2.9 cm apart). 0 = publish every instance.
        table_plane: the table frame the stages read heights in (the pose stage's table path,
            the box-mode clearance, the classifier's shape features, the depth cue of the
            segmentation): 'rig' the extrinsics alone (no table frame without them: every
            part goes to RANSAC, 1.3 s a part); 'observed' the plane found in each view's
            depth (:mod:`tlessbot_ros.core.common.table_plane`, the rig's frame turned onto
            it); 'auto' the rig while the observed plane agrees with it within
            ``table_plane_max_angle_deg`` and ``table_plane_max_offset_m``, else the observed
            plane (and without extrinsics). The table path needs the table to the millimetre:
            on 60 simulated side views (seed 9101, 253 parts, ground-truth boxes and classes)
            a rig 0.2° + 1 mm off scores 0.941 at 5 cm/5°, 0.5° + 3 mm 0.715, 2° + 1 cm 0.545,
            against 0.957 with the exact rig; 'observed' scores 0.964 in all four cases and
            'auto' 0.957 (exact: the rig's very estimates) or 0.964; without extrinsics 0.957
            (docs/bench/table-plane.md).
        table_plane_max_angle_deg, table_plane_max_offset_m: in 'auto', the rig's table is
            kept while the observed plane is within this angle of it and its centre within
            this height (the plane's own noise on simulated D415 depth: 0.01° and 0.1 mm).
    """

    min_roi_points: int = 30
    table_clearance_m: float = 0.004
    verify_accept_fitness: float = 0.9
    verify_rmse_weight: float = 50.0
    fallback_min_fitness: float = 0.1
    lookalike_check: bool = True
    lookalike_tolerance_m: float = 0.002
    lookalike_min_z: float = 2.0
    lookalike_all_views: bool = True
    fragment_overlap: float = 0.5
    table_plane: str = 'auto'
    table_plane_max_angle_deg: float = 0.1
    table_plane_max_offset_m: float = 0.001

    def __post_init__(self) -> None:
        _check(self.min_roi_points >= 3, f'min_roi_points must be at least 3 (a pose needs '
               f'3 points), got {self.min_roi_points}')
        _check(self.table_clearance_m >= 0, f'table_clearance_m must be >= 0 m, got '
               f'{self.table_clearance_m}')
        _check(self.verify_accept_fitness >= 0, 'verify_accept_fitness must be >= 0 (a '
               f'fitness; above 1: always fit every candidate), got '
               f'{self.verify_accept_fitness}')
        _check(self.verify_rmse_weight >= 0 and math.isfinite(self.verify_rmse_weight),
               f'verify_rmse_weight must be a finite value >= 0 (1/m), got '
               f'{self.verify_rmse_weight}')
        _check(0 <= self.fallback_min_fitness <= 1, 'fallback_min_fitness must be in 0..1 '
               f'(a fitness), got {self.fallback_min_fitness}')
        _check(self.lookalike_tolerance_m > 0, 'lookalike_tolerance_m must be > 0 m (e.g. '
               f'0.002), got {self.lookalike_tolerance_m}')
        _check(self.lookalike_min_z >= 0 and math.isfinite(self.lookalike_min_z),
               'lookalike_min_z must be a finite value >= 0 (standard deviations; 0: any '
               f'surplus), got {self.lookalike_min_z}')
        _check(self.table_plane in TABLE_PLANE_MODES, f'table_plane must be one of '
               f'{", ".join(TABLE_PLANE_MODES)}, got {self.table_plane!r}')
        _check(self.table_plane_max_angle_deg >= 0 and self.table_plane_max_offset_m >= 0,
               'table_plane_max_angle_deg and table_plane_max_offset_m must be >= 0')
        _check(0.0 <= self.fragment_overlap < 1.0, 'fragment_overlap must be in [0, 1) (0.5; '
               f'0 turns the check off), got {self.fragment_overlap}')
