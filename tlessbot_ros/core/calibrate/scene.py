"""The rig from what the two cameras see: table planes and the parts both views show.

Each camera sees the table in its depth (:func:`~tlessbot_ros.core.common.find_table_plane`),
which fixes its tilt and its height over the table. What no single view fixes is where the two
cameras stand relative to each other *in* the table plane: a turn about the table normal and a
shift along the table (three numbers, :mod:`.inplane`). The parts on the table fix those: both
cameras see the same parts, and the points above the table of one view, moved by the right
in-plane transform, lie on the surfaces the other view sees.

:class:`SceneCalibrator` accumulates cheap per-frame observations and solves occasionally:

1. *Observation* (:func:`observe_view`, ~1-2 ms a view): every few pixels of the aligned depth
   (about ``point_spacing_m`` apart on the table), those above the table by more than the
   depth noise are part points, grouped into blobs by connected components in the image. Each
   frame keeps per view its plane, its part points (camera frame) and their blob.
2. *Planes*: the median plane of each view over the frames kept, the camera levelled on it
   about its own centre (:func:`~.inplane.level_camera_on_plane`), so each view's points get
   heights over the table and x, y near the prior's.
3. *Coarse in-plane fit*: per blob, the x, y of its upper part and its height; hypotheses from
   one or two blob pairs of one frame (within the prior's gate: ``prior_max_yaw_deg``,
   ``prior_max_shift_m``), each scored on every frame by mutual nearest blobs within
   ``match_distance_m`` (MSAC, Torr & Zisserman, CVIU 2000); the best refitted on its
   matches (:func:`~.inplane.procrustes_2d`).
4. *Fine in-plane fit*: ICP (Besl & McKay, PAMI 1992) of the side view's part points onto the
   top view's, frame by frame, over the three in-plane degrees of freedom, the pair distance
   shrinking to ``icp_distance_m``: visible-surface centroids differ between views by up to a
   part's size; the surfaces themselves agree to the depth noise.

The gauge: the scene cannot tell where the world origin lies on the table nor which way its x
axis points. Both are kept from the prior's top camera (its position in the plane and its
heading); everything else (both tilts and heights, the side camera's position and heading
relative to the top camera) comes from the scene. Compare rigs with :func:`rig_errors`, which
does not depend on the gauge.
"""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from tlessbot_ros.core.calibrate.inplane import (
    inplane_parameters,
    inplane_transform,
    level_camera_on_plane,
    procrustes_2d,
)
from tlessbot_ros.core.common.geometry import rotation_angle_deg, transform_points
from tlessbot_ros.core.common.rig import SIDE, TOP, Rig
from tlessbot_ros.core.common.table_plane import (
    TablePlane,
    TablePlaneParams,
    find_table_plane,
    plane_of_frame,
)

# A bumped camera's table can be far from where the rig expects it: search wider than the
# pipeline's table frame does (10 deg, 5 cm around the rig's plane).
CALIBRATION_PLANE = TablePlaneParams(prior_max_angle_deg=20.0, prior_max_offset_m=0.10)


@dataclass(frozen=True)
class SceneCalibrationParams:
    """How the rig is estimated from the scene, and when the estimate is trusted.

    Attributes:
        point_spacing_m: depth pixels are sampled about this far apart on the table (a stride
            per view from its focal length and distance: 3 px for the top D415 at 1.1 m, 4 px
            for the side one at 0.64 m; 3 mm cost twice the time, no better on synthetic
            scenes).
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
            than they bring (synthetic boxes, 4 scenes of 8 frames: 0.03-0.20 deg with all
            points, 0.05-0.28 with 45 deg).
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


# --------------------------------------------------------------------------- observations
@dataclass(frozen=True)
class ViewObservation:
    """What one view of one frame gives the calibration.

    Attributes:
        plane: (4,) float64 table plane in the camera's optical frame (unit normal towards the
            camera, ``d`` its height).
        points: (N, 3) float32 part points in the optical frame, metres.
        blob: (N,) int32 blob index of each point (0 .. B - 1).
        cut: (B,) bool, blobs touching the image border (only part of a part is seen: their
            centres are not compared, their points are still fitted).
    """

    plane: np.ndarray
    points: np.ndarray
    blob: np.ndarray
    cut: np.ndarray

    @property
    def blobs(self) -> int:
        return len(self.cut)


def view_stride_px(K: np.ndarray, T_world_camera: np.ndarray, spacing_m: float) -> int:
    """The pixel stride that samples the table about ``spacing_m`` apart where the camera's
    optical axis meets it (1 at least)."""
    K = np.asarray(K, np.float64)
    T = np.asarray(T_world_camera, np.float64)
    axis_z = T[2, 2]
    distance = T[2, 3] / -axis_z if axis_z < -1e-3 else np.linalg.norm(T[:3, 3])
    return max(1, int(round(spacing_m * K[0, 0] / max(distance, 1e-3))))


def observe_view(depth_m: np.ndarray, K: np.ndarray, plane: np.ndarray, *, stride_px: int,
                 params: SceneCalibrationParams = SceneCalibrationParams(),
                 rng: np.random.Generator | None = None) -> ViewObservation:
    """The part points of one depth image: above the table, grouped into blobs.

    Args:
        depth_m: (H, W) depth in metres (0, NaN: holes).
        K: (3, 3) camera matrix of the depth.
        plane: (4,) the table in the camera frame, unit normal towards the camera.
        stride_px: every this many pixels in both directions are used.
        params: heights, noise and blob sizes.
        rng: thins a view with more than ``max_points_per_view`` points (None: seed 0).

    Returns:
        :class:`ViewObservation` (no blobs when nothing stands on the table).
    """
    depth_m = np.asarray(depth_m)
    if depth_m.ndim != 2:
        raise ValueError(f'depth must be a 2-D (H, W) array, got shape {depth_m.shape}')
    K = np.asarray(K, np.float64)
    plane = np.asarray(plane, np.float64).reshape(4)
    first = stride_px // 2
    z = depth_m[first::stride_px, first::stride_px].astype(np.float64)
    u = np.arange(z.shape[1]) * float(stride_px) + first
    v = np.arange(z.shape[0]) * float(stride_px) + first
    x_ray, y_ray = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
    # height over the plane = z * (n . ray) + d, with n . ray separable in u and v
    along = plane[0] * x_ray[None, :] + plane[1] * y_ray[:, None] + plane[2]
    with np.errstate(invalid='ignore'):
        valid = np.isfinite(z) & (z > 0)
        z = np.where(valid, z, 0.0)
        height = z * along + plane[3]
        floor = np.maximum(params.min_height_m,
                           params.height_sigmas * params.plane.noise_at_1m_m * z * z)
        above = valid & (height > floor) & (height < params.max_height_m)
    empty = ViewObservation(plane, np.zeros((0, 3), np.float32), np.zeros(0, np.int32),
                            np.zeros(0, bool))
    if not above.any():
        return empty
    count, labels, stats, _ = cv2.connectedComponentsWithStats(above.astype(np.uint8),
                                                                connectivity=8)
    keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= params.min_blob_points) + 1
    if len(keep) == 0:
        return empty
    index = np.full(count, -1, np.int32)
    index[keep] = np.arange(len(keep))
    blob_image = index[labels]
    rows, cols = np.nonzero(blob_image >= 0)
    if len(rows) > params.max_points_per_view:
        rng = rng or np.random.default_rng(params.seed)
        chosen = np.sort(rng.choice(len(rows), params.max_points_per_view, replace=False))
        rows, cols = rows[chosen], cols[chosen]
    depth = z[rows, cols]
    points = np.stack([x_ray[cols] * depth, y_ray[rows] * depth, depth], axis=1)
    x, y, w, h = (stats[keep, k] for k in (cv2.CC_STAT_LEFT, cv2.CC_STAT_TOP,
                                           cv2.CC_STAT_WIDTH, cv2.CC_STAT_HEIGHT))
    cut = (x == 0) | (y == 0) | (x + w >= above.shape[1]) | (y + h >= above.shape[0])
    return ViewObservation(plane, points.astype(np.float32), blob_image[rows, cols], cut)


_NO_POINTS = np.zeros((0, 3), np.float32)
_NO_BLOBS = np.zeros(0, np.int32)
_NO_CUTS = np.zeros(0, bool)


@dataclass(frozen=True)
class FrameObservation:
    """One frame's observations, by view name (only views whose table was found)."""

    views: dict[str, ViewObservation]
    index: int

    def has_parts(self, names: Sequence[str]) -> bool:
        return all(name in self.views and self.views[name].blobs > 0 for name in names)


# --------------------------------------------------------------------------- results
@dataclass(frozen=True)
class RigDifference:
    """How far one camera pose (or the top -> side transform) is from another.

    Attributes:
        angle_deg: rotation between the two.
        offset_m: distance between the two camera centres (for top -> side: between the side
            camera's centres in the top camera's frame).
    """

    angle_deg: float
    offset_m: float

    def exceeds(self, angle_deg: float, offset_m: float) -> bool:
        return self.angle_deg > angle_deg or self.offset_m > offset_m


def pose_difference(T_a: np.ndarray, T_b: np.ndarray) -> RigDifference:
    """:class:`RigDifference` of two (4, 4) poses."""
    return RigDifference(rotation_angle_deg(T_a[:3, :3], T_b[:3, :3]),
                         float(np.linalg.norm(np.asarray(T_a)[:3, 3] - np.asarray(T_b)[:3, 3])))


def rig_differences(reference: Rig, other: Rig, *, top: str = TOP, side: str = SIDE
                    ) -> dict[str, RigDifference]:
    """Per camera name, and ``'top_side'`` for the relative transform, how far ``other`` is
    from ``reference`` (world frames as they are: the per-camera figures depend on the gauge,
    ``top_side`` does not)."""
    out = {name: pose_difference(reference[name].T_world_camera, other[name].T_world_camera)
           for name in reference.cameras if name in other.cameras}
    out['top_side'] = pose_difference(reference.T_a_b(top, side), other.T_a_b(top, side))
    return out


@dataclass(frozen=True)
class RigErrors:
    """Gauge-free errors of an estimated rig against the true one.

    Attributes:
        relative: the top -> side transform's error (angle, and the side camera centre's
            offset in the top camera's frame).
        height_m: per camera, estimated minus true height over the table.
        tilt_deg: per camera, the angle between the table normals seen in the camera frame
            (its tilt and roll over the table).
    """

    relative: RigDifference
    height_m: dict[str, float]
    tilt_deg: dict[str, float]


def rig_errors(truth: Rig, estimate: Rig, *, top: str = TOP, side: str = SIDE) -> RigErrors:
    """:class:`RigErrors` of ``estimate`` against ``truth``; both have world z = 0 the table."""
    heights, tilts = {}, {}
    for name in (top, side):
        T_true, T_est = truth[name].T_world_camera, estimate[name].T_world_camera
        heights[name] = float(T_est[2, 3] - T_true[2, 3])
        # the world z axis in the camera frame: the third row of the rotation
        cos = float(np.clip(T_true[2, :3] @ T_est[2, :3], -1.0, 1.0))
        tilts[name] = float(np.degrees(np.arccos(cos)))
    return RigErrors(pose_difference(truth.T_a_b(top, side), estimate.T_a_b(top, side)),
                     heights, tilts)


@dataclass(frozen=True)
class RigEstimate:
    """The rig the scene shows, and how far to trust it.

    Attributes:
        rig: the estimated rig (the prior's intrinsics; world yaw and origin from the prior's
            top camera).
        prior: the rig it was estimated against (config/cell.yaml).
        levelled: the prior's cameras levelled on the tables they see (tilt and height from
            the scene, in-plane placement from the prior).
        in_plane: (yaw_deg, x_m, y_m) of the in-plane correction applied to the side camera.
        planes: frames whose table was found in both views (in the plane history).
        frames: frames kept with parts in both views; frames_matched: those with a part
            matched between the views; matches: matched blobs in all.
        pairs: point pairs of the fine fit's last iteration.
        residual_m: their RMS distance in the plane.
        overlap: share of the side view's part points within ``icp_distance_m`` of the top
            view's; prior_overlap: the same with the prior's in-plane placement (planes
            levelled): the prior explains the scene this well.
        yaw_sigma_deg, shift_sigma_m: uncertainty of the in-plane fit (spread of the per-frame
            fits over the square root of their number; inf with fewer than two).
        in_plane_solved: whether the parts gave an in-plane fit (else only the planes are
            used: the prior's in-plane placement is kept).
        confident: the in-plane fit meets every threshold of the parameters.
        differences: :func:`rig_differences` of ``rig`` from ``prior``.
        solve_ms: time of the solve.
    """

    rig: Rig
    prior: Rig
    levelled: Rig
    in_plane: tuple[float, float, float] = (0.0, 0.0, 0.0)
    planes: int = 0
    frames: int = 0
    frames_matched: int = 0
    matches: int = 0
    pairs: int = 0
    residual_m: float = float('nan')
    overlap: float = 0.0
    prior_overlap: float = 0.0
    yaw_sigma_deg: float = float('inf')
    shift_sigma_m: float = float('inf')
    in_plane_solved: bool = False
    confident: bool = False
    differences: dict[str, RigDifference] = field(default_factory=dict)
    solve_ms: float = 0.0

    def summary(self) -> str:
        """One line: what the estimate rests on and how far it is from the prior."""
        parts = [f'{self.planes} frames with both tables, {self.frames} with parts in both '
                 f'views, {self.frames_matched} matched, {self.matches} matched parts']
        if self.in_plane_solved:
            parts.append(f'fit residual {1e3 * self.residual_m:.1f} mm, overlap '
                         f'{self.overlap:.2f} (config: {self.prior_overlap:.2f}), sigma '
                         f'{self.yaw_sigma_deg:.2f} deg / {1e3 * self.shift_sigma_m:.1f} mm')
        parts.append('confident' if self.confident else
                     'in-plane from the config' if not self.in_plane_solved else 'not confident')
        return '; '.join(parts)


# --------------------------------------------------------------------------- calibrator
class SceneCalibrator:
    """Accumulates frames of a fixed two-camera rig and estimates the rig from them.

    Args:
        prior: the rig as configured (its intrinsics are used unless a frame gives its own;
            its extrinsics say which plane is the table and fix the gauge).
        params: see :class:`SceneCalibrationParams`.
        top, side: the camera names in ``prior``.

    Example:
        >>> calibrator = SceneCalibrator(rig)
        >>> for depth in frames:                    # {'top': (H, W), 'side': (H, W)} metres
        ...     calibrator.add_frame(depth)
        >>> estimate = calibrator.solve()
        >>> estimate.rig, estimate.confident
    """

    def __init__(self, prior: Rig, *, params: SceneCalibrationParams = SceneCalibrationParams(),
                 top: str = TOP, side: str = SIDE) -> None:
        self.prior = prior
        self.params = params
        self.names = (top, side)
        self.frames: deque[FrameObservation] = deque(maxlen=params.max_frames)
        self.planes: dict[str, deque[np.ndarray]] = {
            name: deque(maxlen=params.plane_history) for name in self.names}
        self.resets = 0
        self.added = 0                 # frames offered
        self._jumps = {name: 0 for name in self.names}
        self._rng = np.random.default_rng(params.seed)

    def clear(self) -> None:
        """Forget every observation (the cameras moved, or a new prior)."""
        self.frames.clear()
        for history in self.planes.values():
            history.clear()

    # ------------------------------------------------------------------- observing
    def add_frame(self, depth_m: Mapping[str, np.ndarray | None], *,
                  K: Mapping[str, np.ndarray] | None = None,
                  planes: Mapping[str, TablePlane | np.ndarray | None] | None = None,
                  parts: bool = True) -> FrameObservation:
        """Observe one frame.

        Args:
            depth_m: per camera name, (H, W) aligned depth in metres (None: not seen).
            K: per camera name, (3, 3) camera matrix (default: the prior's intrinsics).
            planes: per camera name, its table plane if already found (e.g. by the
                pipeline's table frame), else it is found here (``params.plane``, the prior's
                plane as a guide).
            parts: False: only the planes are taken (no part points; the frame is not
                kept).

        Returns:
            the frame's :class:`FrameObservation` (the views whose table was found); it is
            kept when both views show parts.
        """
        self.added += 1
        views = {}
        for name in self.names:
            depth = depth_m.get(name)
            if depth is None:
                continue
            K_view = np.asarray(K[name] if K and name in K else
                                self.prior[name].intrinsics.K, np.float64)
            plane = None if planes is None else planes.get(name)
            if isinstance(plane, TablePlane):
                plane = plane.plane
            if plane is None:
                found = find_table_plane(
                    depth, K_view, params=self.params.plane,
                    prior=plane_of_frame(self.prior[name].T_world_camera))
                plane = None if found is None else found.plane
            if plane is None or not self._accept_plane(name, np.asarray(plane, np.float64)):
                continue
            if not parts:
                views[name] = ViewObservation(np.asarray(plane, np.float64), _NO_POINTS,
                                              _NO_BLOBS, _NO_CUTS)
                continue
            stride = view_stride_px(K_view, self.prior[name].T_world_camera,
                                    self.params.point_spacing_m)
            views[name] = observe_view(depth, K_view, plane, stride_px=stride,
                                       params=self.params, rng=self._rng)
        frame = FrameObservation(views, self.added - 1)
        if len(views) == len(self.names):
            for name, view in views.items():
                self.planes[name].append(view.plane)
            if frame.has_parts(self.names):
                self.frames.append(frame)
        return frame

    def _accept_plane(self, name: str, plane: np.ndarray) -> bool:
        """False for a plane far from the view's history (an outlier, or the first frame
        after the camera moved); the second such frame running starts everything again."""
        history = self.planes[name]
        if not history:
            return True
        median = _median_plane(history)
        angle = np.degrees(np.arccos(np.clip(median[:3] @ plane[:3], -1.0, 1.0)))
        if angle <= self.params.reset_angle_deg and \
                abs(plane[3] - median[3]) <= self.params.reset_offset_m:
            self._jumps[name] = 0
            return True
        self._jumps[name] += 1
        if self._jumps[name] < 2:
            return False
        self.clear()
        self.resets += 1
        self._jumps = {n: 0 for n in self.names}
        return True

    # ------------------------------------------------------------------- solving
    def solve(self) -> RigEstimate | None:
        """The rig the frames kept so far show (None before both tables were seen)."""
        t0 = time.perf_counter()
        top, side = self.names
        if not self.planes[top] or not self.planes[side]:
            return None
        levelled = {name: level_camera_on_plane(self.prior[name].T_world_camera,
                                                _median_plane(self.planes[name]))
                    for name in self.names}
        world = [{name: _world_view(frame.views[name], levelled[name]) for name in self.names}
                 for frame in self.frames]
        coarse = _coarse_fit(world, self.params, top, side) if world else None
        fine = None if coarse is None else _fine_fit(world, coarse, self.params, top, side)
        G = np.eye(4) if fine is None else fine.G
        rig = self._rig({top: levelled[top], side: G @ levelled[side]})
        yaw, x, y = inplane_parameters(G)
        p = self.params
        estimate = RigEstimate(rig, self.prior, self._rig(levelled),
                               (float(np.degrees(yaw)), x, y),
                               planes=min(len(self.planes[top]), len(self.planes[side])),
                               frames=len(self.frames))
        if coarse is not None and fine is not None:
            estimate = replace(
                estimate, frames_matched=coarse.frames_matched, matches=coarse.matches,
                pairs=fine.pairs, residual_m=fine.residual_m, overlap=fine.overlap,
                prior_overlap=fine.prior_overlap, yaw_sigma_deg=fine.yaw_sigma_deg,
                shift_sigma_m=fine.shift_sigma_m, in_plane_solved=True)
            estimate = replace(estimate, confident=bool(
                estimate.frames_matched >= p.min_frames and estimate.matches >= p.min_matches
                and estimate.yaw_sigma_deg <= p.max_yaw_sigma_deg
                and estimate.shift_sigma_m <= p.max_shift_sigma_m
                and estimate.overlap >= p.min_overlap))
        return replace(estimate, differences=rig_differences(self.prior, rig, top=top,
                                                             side=side),
                       solve_ms=1e3 * (time.perf_counter() - t0))


    def _rig(self, poses: Mapping[str, np.ndarray]) -> Rig:
        """The prior with the cameras of ``poses`` (name: T_world_camera) moved."""
        return Rig(cameras={name: replace(mount, T_world_camera=poses[name])
                            if name in poses else mount
                            for name, mount in self.prior.cameras.items()},
                   world_frame=self.prior.world_frame)


def _median_plane(planes: Sequence[np.ndarray]) -> np.ndarray:
    """(4,) the component-wise median of planes, its normal renormalised."""
    median = np.median(np.asarray(planes, np.float64), axis=0)
    scale = np.linalg.norm(median[:3])
    return median / scale


@dataclass
class _WorldView:
    """One view of one frame in its levelled world frame: (N, 3) points and, per usable blob,
    (x, y, height) of its upper part."""

    points: np.ndarray
    features: np.ndarray


def _world_view(view: ViewObservation, T_world_camera: np.ndarray) -> _WorldView:
    points = transform_points(T_world_camera, view.points)
    features = []
    for b in range(view.blobs):
        if view.cut[b]:
            continue
        mine = points[view.blob == b]
        height = float(np.percentile(mine[:, 2], 95))
        upper = mine[mine[:, 2] >= 0.6 * height]
        x, y = upper[:, :2].mean(axis=0)
        features.append((x, y, height))
    return _WorldView(points, np.asarray(features, np.float64).reshape(-1, 3))


# --------------------------------------------------------------------------- coarse fit
@dataclass
class _Coarse:
    G: np.ndarray
    frames_matched: int
    matches: int
    matched: list[int]          # frames with a match


def _padded(arrays: Sequence[np.ndarray]) -> np.ndarray:
    """(F, M, 3) float64, NaN where a frame has fewer than M rows."""
    width = max((len(a) for a in arrays), default=0)
    out = np.full((len(arrays), max(width, 1), 3), np.nan)
    for k, a in enumerate(arrays):
        out[k, :len(a)] = a
    return out


def _match_costs(G_params: np.ndarray, top: np.ndarray, side: np.ndarray,
                 params: SceneCalibrationParams) -> tuple[np.ndarray, np.ndarray]:
    """For H hypotheses (H, 3) (yaw, x, y) and padded features (F, N, 3), (F, M, 3): the
    (H, F, M, N) planar distances (inf where heights disagree or padding) and the mutual
    nearest pairs within ``match_distance_m`` (bool, same shape)."""
    c, s = np.cos(G_params[:, 0]), np.sin(G_params[:, 0])
    sx, sy = side[None, ..., 0], side[None, ..., 1]                     # (1, F, M)
    mx = c[:, None, None] * sx - s[:, None, None] * sy + G_params[:, 1, None, None]
    my = s[:, None, None] * sx + c[:, None, None] * sy + G_params[:, 2, None, None]
    dx = mx[..., None] - top[None, :, None, :, 0]
    dy = my[..., None] - top[None, :, None, :, 1]
    distance = np.hypot(dx, dy)
    heights = np.abs(side[:, :, None, 2] - top[:, None, :, 2]) <= params.match_height_m
    distance = np.where(heights[None] & np.isfinite(distance), distance, np.inf)
    best_n = distance.argmin(axis=3, keepdims=True)
    best_m = distance.argmin(axis=2, keepdims=True)
    shape = distance.shape
    mutual = (np.arange(shape[3])[None, None, None, :] == best_n) & \
        (np.arange(shape[2])[None, None, :, None] == best_m)
    return distance, mutual & (distance < params.match_distance_m)


def _hypotheses(world: list[dict[str, _WorldView]], params: SceneCalibrationParams,
                top: str, side: str, rng: np.random.Generator) -> np.ndarray:
    """(H, 3) (yaw, x, y) from one blob pair (shift only) and from two pairs of one frame
    whose spans agree (the turn that lines the spans up, the shift that lines their middles
    up), inside the prior's gate."""
    singles, doubles = [], []
    for views in world:
        T, S = views[top].features, views[side].features
        if len(T) == 0 or len(S) == 0:
            continue
        i, k = np.nonzero(np.abs(T[:, None, 2] - S[None, :, 2]) <= params.match_height_m)
        singles.append(np.column_stack([np.zeros(len(i)), T[i, 0] - S[k, 0],
                                        T[i, 1] - S[k, 1]]))
        if len(T) < 2 or len(S) < 2:
            continue
        i, j = np.triu_indices(len(T), 1)
        k, m = np.nonzero(~np.eye(len(S), dtype=bool))
        a, b = np.repeat(i, len(k)), np.repeat(j, len(k))       # every top pair ...
        c, d = np.tile(k, len(i)), np.tile(m, len(i))           # ... with every side pair
        span_t, span_s = T[b, :2] - T[a, :2], S[d, :2] - S[c, :2]
        agree = np.abs(np.hypot(*span_t.T) - np.hypot(*span_s.T)) <= params.match_distance_m
        a, b, c, d, span_t, span_s = (x[agree] for x in (a, b, c, d, span_t, span_s))
        yaw = np.arctan2(span_t[:, 1], span_t[:, 0]) - np.arctan2(span_s[:, 1], span_s[:, 0])
        yaw = (yaw + np.pi) % (2 * np.pi) - np.pi
        middle_t, middle_s = (T[a, :2] + T[b, :2]) / 2, (S[c, :2] + S[d, :2]) / 2
        cos, sin = np.cos(yaw), np.sin(yaw)
        doubles.append(np.column_stack([
            yaw, middle_t[:, 0] - (cos * middle_s[:, 0] - sin * middle_s[:, 1]),
            middle_t[:, 1] - (sin * middle_s[:, 0] + cos * middle_s[:, 1])]))
    kept = []
    for found in (singles, doubles):
        found = np.vstack(found) if found else np.zeros((0, 3))
        gate = (np.abs(found[:, 0]) <= np.radians(params.prior_max_yaw_deg)) & \
            (np.hypot(found[:, 1], found[:, 2]) <= params.prior_max_shift_m)
        found = found[gate]
        if len(found) > params.hypotheses:
            found = found[rng.choice(len(found), params.hypotheses, replace=False)]
        kept.append(found)
    # the prior itself competes too: a right rig needs no hypothesis to be found
    return np.vstack([np.zeros((1, 3)), *kept])


def _coarse_fit(world: list[dict[str, _WorldView]], params: SceneCalibrationParams,
                top: str, side: str) -> _Coarse | None:
    """Best hypothesis by MSAC over every frame, refitted on its matches three times."""
    T = _padded([views[top].features for views in world])
    S = _padded([views[side].features for views in world])
    if not (np.isfinite(T).any() and np.isfinite(S).any()):
        return None
    candidates = _hypotheses(world, params, top, side, np.random.default_rng(params.seed))
    best, best_score = None, -np.inf
    for start in range(0, len(candidates), 64):   # bounded memory: (64, F, M, N)
        chunk = candidates[start:start + 64]
        distance, inlier = _match_costs(chunk, T, S, params)
        cost = np.where(inlier, 1.0 - (distance / params.match_distance_m) ** 2, 0.0)
        score = cost.sum(axis=(1, 2, 3))
        k = int(np.argmax(score))
        if score[k] > best_score:
            best, best_score = chunk[k], float(score[k])
    if best is None or best_score <= 0:
        return None
    G = inplane_transform(*best)
    for _ in range(3):
        distance, inlier = _match_costs(np.array(inplane_parameters(G))[None], T, S, params)
        f, m, n = np.nonzero(inlier[0])
        if len(f) == 0:
            return None
        if len(f) == 1:   # one pair fixes the shift only: keep the turn
            moved = transform_points(G, S[f, m])
            G = inplane_transform(0.0, *(T[f, n, :2] - moved[:, :2])[0]) @ G
        else:
            G = procrustes_2d(S[f, m], T[f, n])
    matched = sorted(set(int(k) for k in f))
    return _Coarse(G, len(matched), len(f), matched)


# --------------------------------------------------------------------------- fine fit
def _normals(cloud: np.ndarray, at: np.ndarray, k: int = 10) -> np.ndarray:
    """(M, 3) unit normals at the points ``at`` of a (N, 3) cloud: the direction of least
    spread of their ``k`` nearest neighbours."""
    from scipy.spatial import cKDTree

    k = min(k, len(cloud))
    _, index = cKDTree(cloud).query(at, k=k)
    near = cloud[index.reshape(len(at), k)]
    centred = near - near.mean(axis=1, keepdims=True)
    return np.linalg.eigh(np.einsum('mki,mkj->mij', centred, centred))[1][:, :, 0]


def _thinned(points: np.ndarray, count: int, rng: np.random.Generator) -> np.ndarray:
    """At most ``count`` of the (N, 3) points, chosen at random (seeded)."""
    if len(points) <= count:
        return points
    return points[np.sort(rng.choice(len(points), count, replace=False))]


@dataclass
class _Fine:
    G: np.ndarray
    pairs: int
    residual_m: float
    overlap: float
    prior_overlap: float
    yaw_sigma_deg: float
    shift_sigma_m: float


def _fine_fit(world: list[dict[str, _WorldView]], coarse: _Coarse,
              params: SceneCalibrationParams, top: str, side: str) -> _Fine:
    """In-plane ICP of the side view's part points onto the top view's, over the frames with
    matched parts."""
    from scipy.spatial import cKDTree

    scale = np.array([1.0, 1.0, params.icp_height_weight])
    frames = [world[k] for k in coarse.matched]
    trees = [cKDTree(views[top].points * scale) for views in frames]
    targets = [views[top].points for views in frames]
    rng = np.random.default_rng(params.seed)
    sources = [_thinned(views[side].points, params.icp_points, rng) for views in frames]
    if params.icp_face_tilt_deg < 90.0:
        # Side points on walls the top camera does not see would be pulled onto the nearest
        # top-face edge, a few mm off: points on faces both cameras see carry the fit.
        flat = np.cos(np.radians(params.icp_face_tilt_deg))
        sources = [s[np.abs(_normals(views[side].points, s)[:, 2]) >= flat]
                   for s, views in zip(sources, frames)]

    def pairs(G: np.ndarray, distance: float) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per frame, (moved side points, their nearest top points) within ``distance``."""
        out = []
        for tree, target, source in zip(trees, targets, sources):
            moved = transform_points(G, source)
            gap, index = tree.query(moved * scale, distance_upper_bound=distance)
            near = np.isfinite(gap)
            out.append((moved[near], target[index[near]]))
        return out

    G = coarse.G
    distance = params.icp_start_distance_m
    for _ in range(params.icp_iterations):
        found = pairs(G, distance)
        source = np.concatenate([s for s, _ in found])
        if len(source) < 3:
            break
        step = procrustes_2d(source, np.concatenate([t for _, t in found]))
        G = step @ G
        yaw, x, y = inplane_parameters(step)
        settled = distance <= params.icp_distance_m
        distance = max(params.icp_distance_m, 0.7 * distance)
        if settled and abs(yaw) < 3e-5 and np.hypot(x, y) < 3e-5:   # 0.002 deg, 0.03 mm
            break
    found = pairs(G, params.icp_distance_m)
    total = sum(len(s) for s in sources)
    source = np.concatenate([s for s, _ in found])
    target = np.concatenate([t for _, t in found])
    residual = float(np.sqrt(np.mean(np.sum((source - target)[:, :2] ** 2, axis=1)))) \
        if len(source) else float('nan')
    prior = sum(len(s) for s, _ in pairs(np.eye(4), params.icp_distance_m))
    # per-frame fits from the common solution: their spread says how well it is determined
    steps = np.array([inplane_parameters(procrustes_2d(s, t)) for s, t in found if len(s) >= 10])
    if len(steps) >= 2:
        spread = steps.std(axis=0, ddof=1) / np.sqrt(len(steps))
        yaw_sigma, shift_sigma = float(np.degrees(spread[0])), float(np.hypot(*spread[1:]))
    else:
        yaw_sigma = shift_sigma = float('inf')
    return _Fine(G, len(source), residual, len(source) / max(total, 1), prior / max(total, 1),
                 yaw_sigma, shift_sigma)


__all__ = ['CALIBRATION_PLANE', 'FrameObservation', 'RigDifference', 'RigErrors',
           'RigEstimate', 'SceneCalibrationParams', 'SceneCalibrator', 'ViewObservation',
           'observe_view', 'pose_difference', 'rig_differences',
           'rig_errors', 'view_stride_px']
