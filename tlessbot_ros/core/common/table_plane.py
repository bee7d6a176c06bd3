"""The table (support) plane seen in one depth image, and the table frame it gives.

The table path of the pose stage, the depth cue of the segmentation and the classifier's shape
features read points in a frame whose z = 0 is the table, z up. A rig's extrinsics
(config/cell.yaml, a dataset's ``cam_R_w2c`` / ``cam_t_w2c``) give one, but only as well as the
cell was measured. Here each view finds its support plane in its own depth, as the paper's §3.3
does (RANSAC plane), so that one RGB-D view without extrinsics has a table frame too, and a
rig's frame can be checked against what its camera sees.

* :func:`find_table_plane`: every ``stride_px``-th pixel back-projected with the intrinsics, a
  seeded RANSAC (all hypotheses scored in one pass) whose inlier distance follows the depth
  noise of a stereo camera (sigma = ``noise_at_1m_m`` * z², the D415's 2 mm at 1 m), the plane
  facing the camera that holds most points (with a rig: among those near the rig's table),
  refitted by least squares on its inliers. Parts standing on the table, holes, NaN and zeros
  are outliers or skipped. Its cost per view: docs/bench/table-plane.md.
* :class:`TablePlaneTracker`: smooths a fixed camera's plane over frames; resets on a jump.
* :func:`table_frame_from_plane`: a ``T_world_camera`` whose z = 0 is the plane; its yaw and the
  origin on the table are arbitrary (the foot of the camera centre), which is all the table
  path needs (z = 0 the table, z up).
* :func:`align_frame_to_plane`: a rig's frame turned and shifted the least onto the observed
  plane (keeps the rig's yaw and origin); :func:`plane_difference`: how far the rig's table is
  from the observed one; :func:`choose_table_frame`: the frame a view is read in.

Planes are (4,) float64 ``a, b, c, d`` in the camera optical frame, ``ax + by + cz + d = 0``,
unit normal, oriented towards the camera (``d > 0``: the camera centre lies above the plane).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from tlessbot_ros.core.common.geometry import (
    invert_transform,
    make_transform,
    rotation_about_axis,
)

TABLE_PLANE_MODES = ('rig', 'observed', 'auto')


@dataclass(frozen=True)
class TablePlaneParams:
    """How the table plane is found in a depth image and tracked over frames.

    Attributes:
        stride_px: every this many pixels in both directions are used (8: 4800 of 640x480).
        iterations: RANSAC hypotheses (three points each), scored all at once.
        score_points: the hypotheses are scored on this many of the points (seeded subset);
            the winner is refitted on all of them.
        noise_at_1m_m: depth noise (standard deviation) at 1 m; it grows with z² (stereo). The
            D415: 2.1 mm (0.07 px sub-pixel disparity error, 55 mm baseline, 615 px).
        inlier_sigmas: a point within this many noise sigmas (at its depth) of a plane is an
            inlier of it.
        min_inlier_distance_m, max_inlier_distance_m: bounds of the inlier distance (1 mm
            depth quantisation below; far, noisy points above).
        max_depth_m: points farther than this are not used (the room beyond the table).
        max_incidence_deg: a plane is the table only if the camera sees it at most this far
            from its normal (a wall seen edge-on is not).
        min_inlier_share: no table is found when the best plane holds a smaller share of the
            valid points.
        min_image_share: ... or covers a smaller share of the image (sampled pixels, valid or
            not): a depth image that shows little but a part has no table in it, only the
            part's faces.
        refits: least-squares refits of the winner (inliers recomputed each time; after the
            first, the inlier distance follows the noise measured on the plane).
        prior_max_angle_deg, prior_max_offset_m: with a rig, only planes this close to the
            rig's table are candidates (angle between the normals; difference of the camera's
            height above them).
        smoothing: :class:`TablePlaneTracker`: weight of a new observation (1: no smoothing).
        reset_angle_deg, reset_offset_m: the tracker starts again from a new observation that
            differs from its plane by more than this (the camera moved).
        hold_frames: the tracker keeps its plane through this many frames without one.
        seed: seeds the point subset and the hypotheses (the same depth gives the same plane).
    """

    stride_px: int = 8
    iterations: int = 200
    score_points: int = 1500
    noise_at_1m_m: float = 0.0021
    inlier_sigmas: float = 3.0
    min_inlier_distance_m: float = 0.002
    max_inlier_distance_m: float = 0.02
    max_depth_m: float = 2.0
    max_incidence_deg: float = 80.0
    min_inlier_share: float = 0.15
    min_image_share: float = 0.1
    refits: int = 2
    prior_max_angle_deg: float = 10.0
    prior_max_offset_m: float = 0.05
    smoothing: float = 0.3
    reset_angle_deg: float = 1.0
    reset_offset_m: float = 0.005
    hold_frames: int = 15
    seed: int = 0

    def __post_init__(self) -> None:
        if self.stride_px < 1 or self.iterations < 1 or self.score_points < 3:
            raise ValueError('stride_px and iterations must be >= 1, score_points >= 3')
        if self.noise_at_1m_m < 0 or self.inlier_sigmas <= 0 or \
                not 0 <= self.min_inlier_distance_m <= self.max_inlier_distance_m:
            raise ValueError('noise_at_1m_m must be >= 0, inlier_sigmas > 0 and '
                             '0 <= min_inlier_distance_m <= max_inlier_distance_m')
        if not 0.0 < self.max_incidence_deg < 90.0:
            raise ValueError(f'max_incidence_deg must be in (0, 90), got '
                             f'{self.max_incidence_deg}')
        if not (0.0 <= self.min_inlier_share <= 1.0 and 0.0 <= self.min_image_share <= 1.0
                and 0.0 < self.smoothing <= 1.0):
            raise ValueError('min_inlier_share and min_image_share must be in [0, 1], '
                             'smoothing in (0, 1]')


@dataclass(frozen=True)
class TablePlane:
    """A table plane found in one view.

    Attributes:
        plane: (4,) a, b, c, d in the camera optical frame (unit normal towards the camera).
        inlier_share: share of the valid sampled points on the plane.
        n_points: valid sampled points.
        centroid: (3,) centroid of the inliers, camera frame, metres (where the table is seen).
        noise_at_1m_m: the depth noise measured on the plane (sigma at 1 m, m; residuals over
            z²), or None when not measured (no refit).
    """

    plane: np.ndarray
    inlier_share: float
    n_points: int
    centroid: np.ndarray
    noise_at_1m_m: float | None = None

    @property
    def normal(self) -> np.ndarray:
        return self.plane[:3]

    @property
    def camera_height_m(self) -> float:
        """Distance of the camera centre from the plane."""
        return float(self.plane[3])


def sampled_points(depth_m: np.ndarray, K: np.ndarray, stride_px: int, *,
                   max_depth_m: float = np.inf) -> np.ndarray:
    """(N, 3) float64 optical-frame points of every ``stride_px``-th pixel with valid depth
    (row-major order).

    Args:
        depth_m: (H, W) depth in metres; 0, negative and non-finite values are invalid.
        K: (3, 3) camera matrix of the (aligned) depth.
        max_depth_m: farther pixels are left out too.
    """
    depth_m = np.asarray(depth_m)
    if depth_m.ndim != 2:
        raise ValueError(f'depth must be a 2-D (H, W) array, got shape {depth_m.shape}')
    from tlessbot_ros.core.common.plane_kernels import sampled_points as sample

    return sample(depth_m, int(stride_px), float(K[0, 2]), float(K[1, 2]), float(K[0, 0]),
                  float(K[1, 1]), float(max_depth_m))


def _inlier_distance(points: np.ndarray, params: TablePlaneParams) -> np.ndarray:
    """(N,) inlier distance of each point: ``inlier_sigmas`` noise sigmas at its depth."""
    sigma = params.noise_at_1m_m * points[:, 2] ** 2
    return np.clip(params.inlier_sigmas * sigma, params.min_inlier_distance_m,
                   params.max_inlier_distance_m)


def _facing(normals: np.ndarray, offsets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Planes turned so that the camera centre lies on their positive side (d >= 0)."""
    sign = np.where(offsets < 0, -1.0, 1.0)
    return normals * sign[..., None], offsets * sign


def _hypotheses(points: np.ndarray, params: TablePlaneParams, rng: np.random.Generator
                ) -> tuple[np.ndarray, np.ndarray]:
    """(H, 3) unit normals and (H,) offsets of planes through random point triples that face
    the camera within ``max_incidence_deg``; degenerate triples are left out."""
    from tlessbot_ros.core.common.plane_kernels import triple_normals

    triples = points[rng.integers(0, len(points), (params.iterations, 3))]   # (H, 3, 3)
    normals, firsts, seen_at = triple_normals(triples)
    # (numpy's einsum sums these three products in an order of its own: kept here)
    normals, offsets = _facing(normals, -np.einsum('hi,hi->h', normals, firsts))
    # cos(incidence) at the triple's centre: the camera's distance to the plane over its
    # distance to the points
    facing = offsets >= np.cos(np.radians(params.max_incidence_deg)) * seen_at
    return normals[facing], offsets[facing]


def _distances(points: np.ndarray, normal: np.ndarray, offset: float) -> np.ndarray:
    """(N,) signed distances of the points to a plane (element-wise: no BLAS call)."""
    distances: np.ndarray = points[:, 0] * normal[0] + points[:, 1] * normal[1] \
        + points[:, 2] * normal[2] + offset
    return distances


def _near_prior(normals: np.ndarray, offsets: np.ndarray, prior: np.ndarray,
                params: TablePlaneParams) -> tuple[np.ndarray, np.ndarray]:
    """The hypotheses within ``prior_max_angle_deg`` and ``prior_max_offset_m`` (camera
    height) of the rig's plane, plus that plane itself: the rig says which surface is the
    table (not the wall behind it), the depth says exactly where it is."""
    prior = np.asarray(prior, np.float64).reshape(4)
    scale = np.linalg.norm(prior[:3])
    if not scale > 0:
        raise ValueError(f'prior plane has a zero normal: {prior}')
    normal, offset = _facing(prior[:3] / scale, np.array(prior[3] / scale))
    near = (normals @ normal >= np.cos(np.radians(params.prior_max_angle_deg))) & \
        (np.abs(offsets - offset) <= params.prior_max_offset_m)
    return np.vstack([normals[near], normal]), np.append(offsets[near], offset)


def _robust_refit(points: np.ndarray, normal: np.ndarray, offset: float,
                  params: TablePlaneParams
                  ) -> tuple[np.ndarray, float, np.ndarray | None, float | None]:
    """The RANSAC winner refitted ``refits`` times by least squares on its inliers; after the
    first fit the inlier distance follows the noise measured on the plane (median absolute
    residual over z², as sigma at 1 m), so a clean sensor gets a tight band (part bottoms
    stay out) and a noisy one keeps its whole table. Returns the plane, its (N,) inlier
    mask (None: too few inliers) and the noise measured last (sigma at 1 m; None: no refit)."""
    from tlessbot_ros.core.common import plane_kernels as kernels

    inliers = kernels.near_plane(points, normal, offset, _inlier_distance(points, params))
    noise_at_1m = None
    for _ in range(params.refits):
        if inliers.sum() < 3:
            return normal, offset, None, None
        normal, offset = _refit(points, inliers)
        residual, ratio = kernels.residuals(points, normal, offset, inliers)
        noise_at_1m = 1.4826 * float(kernels.median_in_place(ratio))
        inliers = kernels.within_noise(points, residual, params.inlier_sigmas * noise_at_1m,
                                       params.min_inlier_distance_m,
                                       params.max_inlier_distance_m)
    return normal, offset, inliers, noise_at_1m


def _refit(points: np.ndarray, inliers: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit normal towards the camera, offset) of the inlier points: the
    direction of least spread of their scatter matrix."""
    from tlessbot_ros.core.common.plane_kernels import centre_and_scatter

    centre, scatter = centre_and_scatter(points, inliers)
    normal = np.linalg.eigh(scatter)[1][:, 0]
    normal, offset = _facing(normal, np.array(-normal @ centre))
    return normal, float(offset)


def find_table_plane(depth_m: np.ndarray, K: np.ndarray, *,
                     params: TablePlaneParams = TablePlaneParams(),
                     prior: np.ndarray | None = None) -> TablePlane | None:
    """The table plane in one depth image: the largest plane facing the camera.

    Args:
        depth_m: (H, W) depth in metres (aligned or not: ``K`` is the depth's matrix); 0 and
            NaN are holes.
        K: (3, 3) camera matrix.
        params: sampling, RANSAC and noise settings.
        prior: (4,) the plane the rig expects (camera frame), or None. It tells which
            surface is the table: only planes within ``prior_max_angle_deg`` and
            ``prior_max_offset_m`` of it are considered, and it enters as one more hypothesis
            (a rig that is right seeds the fit). What is returned is always fitted to the
            depth, never the prior itself.

    Returns:
        the plane, or None when the depth holds too few valid points or no plane facing the
        camera holds ``min_inlier_share`` of them and ``min_image_share`` of the image.

    Raises:
        ValueError: ``depth_m`` is not 2-D or ``K`` not 3x3.
    """
    K = np.asarray(K, np.float64)
    if K.shape != (3, 3):
        raise ValueError(f'K must be 3x3, got shape {K.shape}')
    points = sampled_points(depth_m, K, params.stride_px, max_depth_m=params.max_depth_m)
    if len(points) < 3:
        return None
    rng = np.random.default_rng(params.seed)
    subset = points if len(points) <= params.score_points else \
        points[rng.choice(len(points), params.score_points, replace=False)]
    normals, offsets = _hypotheses(subset, params, rng)
    if prior is not None:
        normals, offsets = _near_prior(normals, offsets, prior, params)
    if len(normals) == 0:
        return None
    from tlessbot_ros.core.common import plane_kernels as kernels  # numba: 1.7 s import

    counts = kernels.count_inliers(subset, normals, offsets, _inlier_distance(subset, params))
    best = int(np.argmax(counts))
    normal, offset, inliers, noise = _robust_refit(points, normals[best], float(offsets[best]),
                                                   params)
    if inliers is None:
        return None
    count = int(inliers.sum())
    share = count / len(inliers)
    pixels = len(range(params.stride_px // 2, np.shape(depth_m)[0], params.stride_px)) * \
        len(range(params.stride_px // 2, np.shape(depth_m)[1], params.stride_px))
    if share < params.min_inlier_share or count < params.min_image_share * pixels:
        return None
    return TablePlane(np.append(normal, offset), share, len(points),
                      kernels.centre_and_scatter(points, inliers)[0], noise)


class TablePlaneTracker:
    """The table plane of one fixed camera over frames: each observation is blended into the
    tracked plane (weight ``smoothing``); one that differs by more than ``reset_angle_deg`` or
    ``reset_offset_m`` (the camera moved) replaces it; through frames without an observation
    the last plane is kept for ``hold_frames`` frames."""

    def __init__(self, params: TablePlaneParams = TablePlaneParams()) -> None:
        self.params = params
        self.plane: TablePlane | None = None
        self.missed = 0
        self.resets = 0

    def update(self, observed: TablePlane | None) -> TablePlane | None:
        """The tracked plane after this frame's observation (None: no table seen here)."""
        p = self.params
        if observed is None:
            self.missed += 1
            if self.missed > p.hold_frames:
                self.plane = None
            return self.plane
        self.missed = 0
        if self.plane is None or self._jumped(self.plane, observed):
            self.resets += self.plane is not None
            self.plane = observed
            return observed
        old = self.plane.plane
        blended = (1.0 - p.smoothing) * old + p.smoothing * observed.plane
        blended /= np.linalg.norm(blended[:3])
        self.plane = TablePlane(blended, observed.inlier_share, observed.n_points,
                                observed.centroid, observed.noise_at_1m_m)
        return self.plane

    def _jumped(self, tracked: TablePlane, observed: TablePlane) -> bool:
        old = tracked.plane
        angle = np.degrees(np.arccos(np.clip(old[:3] @ observed.normal, -1.0, 1.0)))
        shift = abs(old[:3] @ observed.centroid + old[3])
        return bool(angle > self.params.reset_angle_deg or shift > self.params.reset_offset_m)


# ------------------------------------------------------------------------------- frames
def table_frame_from_plane(plane: np.ndarray, *, points_above: np.ndarray | None = None
                           ) -> np.ndarray:
    """A ``T_world_camera`` whose world z = 0 is a table plane (z up, towards the camera).

    Its yaw (world x along the image's x as far as the plane allows) and its origin (the foot
    of the camera centre on the plane) are arbitrary: without a rig nothing fixes them, and the
    table path needs only z = 0 the table and z up.

    Args:
        plane: (4,) a, b, c, d of the plane in the camera frame (e.g. :func:`find_table_plane`).
        points_above: unused placeholder for a future orientation check; the normal is turned
            towards the camera, which always looks at the table from above.
    """
    n = np.asarray(plane[:3], np.float64)
    norm = np.linalg.norm(n)
    if norm < 1e-9:
        raise ValueError('plane normal is zero')
    n, d = _facing(n / norm, np.array(float(plane[3]) / norm))
    origin = -float(d) * n  # the foot of the camera centre on the plane
    x = np.cross([0.0, 1.0, 0.0], n)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], n)
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    T_camera_world = make_transform(np.stack([x, y, n], axis=1), origin)
    return invert_transform(T_camera_world)


def plane_of_frame(T_world_camera: np.ndarray) -> np.ndarray:
    """(4,) the table plane (world z = 0) of a ``T_world_camera``, in the camera frame."""
    T_world_camera = np.asarray(T_world_camera, np.float64)
    return np.append(T_world_camera[2, :3], T_world_camera[2, 3])


def _plane_in_world(T_world_camera: np.ndarray, plane: np.ndarray) -> tuple[np.ndarray, float]:
    """(3,) unit normal and offset of a camera-frame plane in the world frame."""
    R, t = T_world_camera[:3, :3], T_world_camera[:3, 3]
    normal = R @ plane[:3]
    return normal, float(plane[3] - normal @ t)


def align_frame_to_plane(T_world_camera: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """The rig's ``T_world_camera`` turned and shifted the least so that its z = 0 is the
    observed plane: the rotation that takes the plane's normal onto world z, about the world
    origin, then a vertical shift. The rig's yaw and origin are kept (up to that tilt), so the
    two cameras' frames still agree where the rig was right."""
    T_world_camera = np.asarray(T_world_camera, np.float64)
    normal, offset = _plane_in_world(T_world_camera, np.asarray(plane, np.float64))
    axis = np.cross(normal, [0.0, 0.0, 1.0])
    angle = float(np.arctan2(np.linalg.norm(axis), normal[2]))
    if np.linalg.norm(axis) < 1e-12:   # parallel (no turn) or opposite (half turn about x)
        axis = np.array([1.0, 0.0, 0.0])
    R = rotation_about_axis(axis, angle)
    return cast(np.ndarray, make_transform(R, [0.0, 0.0, offset]) @ T_world_camera)


def plane_difference(T_world_camera: np.ndarray, table: TablePlane) -> tuple[float, float]:
    """How far the rig's table (world z = 0) is from the observed one.

    Returns:
        (angle between the two normals in degrees, height in metres of the observed table's
        centre (:attr:`TablePlane.centroid`) above the rig's table).
    """
    T_world_camera = np.asarray(T_world_camera, np.float64)
    normal, _ = _plane_in_world(T_world_camera, table.plane)
    angle = float(np.degrees(np.arccos(np.clip(normal[2], -1.0, 1.0))))
    height = float(T_world_camera[2, :3] @ table.centroid + T_world_camera[2, 3])
    return angle, height


@dataclass(frozen=True)
class TableFrame:
    """The table frame one view is read in.

    Attributes:
        T_world_camera: (4, 4) camera pose in a frame whose z = 0 is the table (z up), or None
            (no extrinsics and no plane found).
        source: 'rig' (the given extrinsics), 'observed' (from the plane in the depth) or
            'none'.
        observed: the (tracked) plane seen in the depth, or None when it was not looked for
            or not found.
        rig_angle_deg, rig_offset_m: :func:`plane_difference` of the rig and the observed
            plane (None without either).
        find_ms: time spent finding the plane.
    """

    T_world_camera: np.ndarray | None
    source: str
    observed: TablePlane | None = None
    rig_angle_deg: float | None = None
    rig_offset_m: float | None = None
    find_ms: float = 0.0


def choose_table_frame(T_rig: np.ndarray | None, observed: TablePlane | None, *, mode: str,
                       max_angle_deg: float, max_offset_m: float,
                       find_ms: float = 0.0) -> TableFrame:
    """The frame a view is read in, from the rig's extrinsics and the observed plane.

    Args:
        T_rig: the view's ``T_world_camera`` from the rig, or None (no extrinsics).
        observed: the plane seen in its depth, or None.
        mode: 'rig': the rig's frame (none without extrinsics); 'observed': the observed
            plane (aligned to the rig's frame when there is one, see
            :func:`align_frame_to_plane`); 'auto': the rig's frame unless the observed plane
            differs from it by more than ``max_angle_deg`` or ``max_offset_m``. Without
            extrinsics 'observed' and 'auto' use the observed plane; without a plane, the rig.
    """
    if mode not in TABLE_PLANE_MODES:
        raise ValueError(f'table plane mode must be one of {TABLE_PLANE_MODES}, got {mode!r}')
    angle = offset = None
    if T_rig is not None and observed is not None:
        angle, offset = plane_difference(T_rig, observed)
    if observed is None or mode == 'rig' or (
            mode == 'auto' and angle is not None and offset is not None and angle <= max_angle_deg
            and abs(offset) <= max_offset_m):
        source = 'none' if T_rig is None else 'rig'
        return TableFrame(T_rig, source, observed, angle, offset, find_ms)
    T = table_frame_from_plane(observed.plane) if T_rig is None else \
        align_frame_to_plane(T_rig, observed.plane)
    return TableFrame(T, 'observed', observed, angle, offset, find_ms)


def above_table(points_c: np.ndarray, frame: TableFrame, ceiling_m: float,
                params: TablePlaneParams | None = None) -> np.ndarray:
    """The points of ``points_c`` ((N, 3), camera frame, m) higher than ``ceiling_m`` above the
    table of ``frame`` (which must have a ``T_world_camera``); with ``params``, higher than the
    table's own points reach at their depth where that is lower: the plane fit's inlier
    distance (``inlier_sigmas`` sigmas of the noise measured on the plane, else of
    ``params.noise_at_1m_m``, times z², at least ``min_inlier_distance_m``)."""
    from tlessbot_ros.core.common.geometry import transform_points

    clearance = np.full(len(points_c), ceiling_m)
    if params is not None:
        observed = frame.observed
        noise = params.noise_at_1m_m if observed is None or observed.noise_at_1m_m is None \
            else observed.noise_at_1m_m
        band = np.clip(params.inlier_sigmas * noise * points_c[:, 2] ** 2,
                       params.min_inlier_distance_m, None)
        clearance = np.minimum(band, ceiling_m)
    height = transform_points(np.asarray(frame.T_world_camera), points_c)[:, 2]
    return points_c[height > clearance]
