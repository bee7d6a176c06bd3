"""The settings of the scene calibration (:mod:`.scene`): sampling, matching, fitting and the
thresholds of a trusted estimate."""
from __future__ import annotations

from dataclasses import dataclass

from tlessbot_ros.core.common.table_plane import TablePlaneParams

# A bumped camera's table can be far from where the rig expects it: search wider than the
# pipeline's table frame does (10 deg, 5 cm around the rig's plane).
CALIBRATION_PLANE = TablePlaneParams(prior_max_angle_deg=20.0, prior_max_offset_m=0.10)


@dataclass(frozen=True)
class SceneCalibrationParams:
    """How the rig is estimated from the scene, and when the estimate is trusted.

    Attributes:
        point_spacing_m: depth pixels are sampled about this far apart on the table (a stride
            per view from its focal length and distance: 3 px for the top D415 at 1.1 m, 4 px
            for the side one at 0.64 m; denser costs time for no gain on synthetic scenes,
            docs/bench/code-figures.md).
        min_height_m: a point is a part's when it is higher above the table than this and than
            ``height_sigmas`` times the depth noise at its distance.
        height_sigmas: ... (noise: ``plane.noise_at_1m_m`` times z squared, z in metres).
        max_height_m: higher points are not parts (an arm, a person).
        min_blob_points: blobs (connected part points in the image) with fewer points are noise.
        max_points_per_view: a view's part points of one frame are thinned to this many.
        prior_max_yaw_deg: the in-plane turn between the views may differ from the prior's by
            at most this (each camera up to 15 degrees off).
        prior_max_shift_m: ... and the in-plane shift at the world origin by at most this
            (each camera up to 5 cm off, plus the turn's lever arm).
        match_distance_m: blobs of the two views are the same part when their upper parts'
            x, y lie this close (what each view sees of a part differs by up to a part's
            half size).
        match_height_m: ... and their heights this close.
        hypotheses: at most this many coarse hypotheses of each kind (one pair, two pairs).
        icp_iterations: iterations of the fine fit.
        icp_points: the side view's points of a frame are thinned to this many for the fine
            fit (the top view's are all used).
        icp_start_distance_m, icp_distance_m: the fine fit's pair distance starts at the first
            and shrinks to the second (a few depth-noise sigmas).
        icp_face_tilt_deg: only side points whose surface (normal of their neighbours) is
            within this of horizontal are fitted (90: all, the default): the top camera sees
            little of the walls the side camera sees, but on noisy depth the normals cost more
            than they bring (docs/bench/code-figures.md).
        icp_height_weight: heights count this much in the fine fit's nearest-neighbour
            distance (the top view's depth noise is mostly vertical, and the fit moves nothing
            vertically).
        max_frames: the latest this many frames with parts in both views are kept.
        plane_history: the latest this many planes of each view are kept (frames without
            parts count).
        min_frames: the in-plane fit is trusted only from this many frames with matched parts
            ...
        min_matches: ... this many matched blobs in all ...
        max_yaw_sigma_deg, max_shift_sigma_m: ... and an uncertainty (spread of the per-frame
            fits over the square root of their number) below these.
        min_overlap: ... and this share of the side view's part points within
            ``icp_distance_m`` of the top view's.
        reset_angle_deg, reset_offset_m: a view whose plane differs from its history by more
            than this in two frames running has moved: everything is collected again.
        plane: the table-plane search (wider prior gates than the pipeline's).
        seed: seeds the thinning and the hypotheses (same frames, same rig).
    """

    point_spacing_m: float = 0.0045
    min_height_m: float = 0.005
    height_sigmas: float = 3.0
    max_height_m: float = 0.30
    min_blob_points: int = 15
    max_points_per_view: int = 1500
    prior_max_yaw_deg: float = 30.0
    prior_max_shift_m: float = 0.15
    match_distance_m: float = 0.025
    match_height_m: float = 0.015
    hypotheses: int = 300
    icp_iterations: int = 30
    icp_points: int = 300
    icp_face_tilt_deg: float = 90.0
    icp_start_distance_m: float = 0.025
    icp_distance_m: float = 0.006
    icp_height_weight: float = 0.5
    max_frames: int = 20
    plane_history: int = 60
    min_frames: int = 3
    min_matches: int = 6
    max_yaw_sigma_deg: float = 0.3
    max_shift_sigma_m: float = 0.003
    min_overlap: float = 0.3
    reset_angle_deg: float = 2.0
    reset_offset_m: float = 0.01
    plane: TablePlaneParams = CALIBRATION_PLANE
    seed: int = 0

    def __post_init__(self) -> None:
        positive = ('point_spacing_m', 'height_sigmas', 'max_height_m', 'match_distance_m',
                    'match_height_m', 'icp_start_distance_m', 'icp_distance_m',
                    'prior_max_yaw_deg', 'prior_max_shift_m')
        bad = [name for name in positive if not getattr(self, name) > 0]
        if bad:
            raise ValueError(f'{", ".join(bad)} must be > 0')
        counts = ('min_blob_points', 'max_points_per_view', 'hypotheses', 'icp_iterations',
                  'icp_points',
                  'max_frames', 'plane_history', 'min_frames', 'min_matches')
        bad = [name for name in counts if getattr(self, name) < 1]
        if bad:
            raise ValueError(f'{", ".join(bad)} must be >= 1')
        if not 0 <= self.min_height_m < self.max_height_m:
            raise ValueError('min_height_m must be in [0, max_height_m)')
        if self.icp_distance_m > self.icp_start_distance_m:
            raise ValueError('icp_distance_m must not exceed icp_start_distance_m')
        if not 0.0 <= self.min_overlap <= 1.0:
            raise ValueError(f'min_overlap must be in [0, 1], got {self.min_overlap}')


__all__ = ['CALIBRATION_PLANE', 'SceneCalibrationParams']
