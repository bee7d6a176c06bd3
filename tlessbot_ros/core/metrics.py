"""6D pose error measures and recalls, as defined by the BOP benchmark.

References:
    [BOP18] Hodaň et al., "BOP: Benchmark for 6D Object Pose Estimation", ECCV 2018
        (VSD with tau = 20 mm, delta = 15 mm, correct if e_VSD < 0.3).
    [BOP20] Hodaň et al., "BOP Challenge 2020 on 6D Object Localization", ECCV-W 2020
        (VSD / MSSD / MSPD and their Average Recalls).
    [ADD] Hinterstoisser et al., "Model Based Training, Detection and Pose Estimation of
        Texture-Less 3D Objects in Heavily Cluttered Scenes", ACCV 2012 (ADD, ADD-S / ADI).
    The definitions follow bop_toolkit ``pose_error.py`` and ``visibility.py``.

Poses are (4, 4) float64 ``T_camera_object`` transforms in metres; model points are (N, 3)
in metres in the model frame; depth images are (H, W) in metres with 0 (or NaN) = no data.
Symmetries are :class:`~tlessbot_ros.core.common.Symmetries`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy.spatial import cKDTree

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    MeshRenderer,
    Symmetries,
    invert_transform,
    make_transform,
    project_points,
    rotation_about_axis,
)

__all__ = [
    'Symmetries', 'PoseError', 'pose_error', 'is_correct_cm_deg', 'add', 'adds', 'mssd', 'mspd',
    'ModelDepthRenderer', 'vsd_from_depth', 'vsd', 'box_iou', 'recall',
    'BOP19_THRESHOLDS', 'BOP19_MSPD_THRESHOLDS_PX', 'average_recall',
    'count_duplicates', 'duplicate_radius_m']

#: BOP'19 correctness thresholds: MSSD (× diameter), VSD tau (× diameter) and VSD theta.
BOP19_THRESHOLDS = np.arange(0.05, 0.501, 0.05)
#: BOP'19 MSPD thresholds in pixels for a 640-pixel-wide image (scale by width / 640).
BOP19_MSPD_THRESHOLDS_PX = np.arange(5.0, 50.01, 5.0)


def _check_pose(T: np.ndarray, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f'{name} must be a 4x4 transform, got shape {T.shape}')
    return T


def _check_points(points: np.ndarray) -> np.ndarray:
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] != 3 or len(points) == 0:
        raise ValueError(f'model points must be a non-empty (N, 3) array, got {points.shape}')
    return points


# ------------------------------------------------------------------------------------------------
# Rotation / translation error


@dataclass(frozen=True)
class PoseError:
    """Symmetry-aware pose error.

    Attributes:
        rotation_deg: geodesic angle between the estimated and the nearest symmetric
            equivalent of the ground-truth rotation, degrees in [0, 180].
        translation_m: distance between the translations of the estimate and of that same
            symmetric equivalent, metres.
    """

    rotation_deg: float
    translation_m: float

    @property
    def ranking(self) -> float:
        """One number to pair estimates with parts by: degrees + millimetres (1° ~ 1 mm)."""
        return self.rotation_deg + 1e3 * self.translation_m


def pose_error(T_est: np.ndarray, T_gt: np.ndarray,
               symmetries: Symmetries | None = None) -> PoseError:
    """Rotation and translation error, minimised over the model's symmetries.

    For every symmetry ``S`` the ground truth ``T_gt @ S`` is an equally correct answer. The
    returned errors belong to the ``S`` with the smallest rotation error. A continuous axis
    ``a`` is handled exactly: with ``Q = R_d R_est^T R_gt`` (``R_d`` a discrete symmetry),
    ``max_theta trace(Q R_a(theta)) = a^T Q a + sqrt(c1^2 + c2^2)``, where
    ``c1 = trace(Q) - a^T Q a`` and ``c2 = trace(Q [a]_x)``. Without symmetries this is
    BOP's ``re`` / ``te``.

    Args:
        T_est, T_gt: (4, 4) poses (metres).
        symmetries: the model's symmetries (default: none).

    Returns:
        :class:`PoseError`.
    """
    T_est = _check_pose(T_est, 'T_est')
    T_gt = _check_pose(T_gt, 'T_gt')
    symmetries = symmetries or Symmetries()
    if len(symmetries.continuous) > 1:  # e.g. a sphere: fall back to sampling
        best = None
        for S in symmetries.transforms(step_rad=np.radians(0.5)):
            candidate = T_gt @ S
            error = _rotation_deg(T_est[:3, :3], candidate[:3, :3])
            if best is None or error < best[0]:
                best = (error, candidate)
        assert best is not None
        return PoseError(best[0], float(np.linalg.norm(T_est[:3, 3] - best[1][:3, 3])))
    best_error, best_S = np.inf, np.eye(4)
    for D in symmetries.discrete:
        if symmetries.continuous:
            axis, offset = symmetries.continuous[0]
            Q = D[:3, :3] @ T_est[:3, :3].T @ T_gt[:3, :3]
            aQa = axis @ Q @ axis
            skew = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]],
                             [-axis[1], axis[0], 0]])
            c1 = np.trace(Q) - aQa
            c2 = np.trace(Q @ skew)
            theta = float(np.arctan2(c2, c1))
            R_c = rotation_about_axis(axis, theta)
            S = make_transform(R_c, offset - R_c @ offset) @ D
        else:
            S = D
        error = _rotation_deg(T_est[:3, :3], T_gt[:3, :3] @ S[:3, :3])
        if error < best_error - 1e-9:
            best_error, best_S = error, S
    T_sym = T_gt @ best_S
    return PoseError(float(best_error), float(np.linalg.norm(T_est[:3, 3] - T_sym[:3, 3])))


def _rotation_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    cos = (np.trace(R_a.T @ R_b) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def is_correct_cm_deg(error: PoseError, *, translation_m: float = 0.05,
                      rotation_deg: float = 5.0) -> bool:
    """The n cm / n° acceptance: the paper's 5 cm / 5° by default (use 0.01 m for 1 cm / 5°)."""
    return error.translation_m < translation_m and error.rotation_deg < rotation_deg


# ------------------------------------------------------------------------------------------------
# Point-distance errors


def add(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray) -> float:
    """ADD [ADD]: mean distance between model points moved by the two poses, metres.

    Args:
        T_est, T_gt: (4, 4) poses in metres.
        points: (N, 3) model points (vertices or surface samples) in metres.
    """
    points = _check_points(points)
    T_est, T_gt = _check_pose(T_est, 'T_est'), _check_pose(T_gt, 'T_gt')
    diff = points @ (T_est[:3, :3] - T_gt[:3, :3]).T + (T_est[:3, 3] - T_gt[:3, 3])
    return float(np.linalg.norm(diff, axis=1).mean())


def adds(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray) -> float:
    """ADD-S / ADI [ADD]: mean distance from each GT point to the closest estimated point, m.

    Symmetry-aware without knowing the symmetries. Correct if below 0.1 × diameter. The
    direction (GT to estimate) and the use of every given point are those of the BOP
    toolkit's ``adi``: pass all the model's vertices to agree with it.
    """
    points = _check_points(points)
    T_est, T_gt = _check_pose(T_est, 'T_est'), _check_pose(T_gt, 'T_gt')
    moved_est = points @ T_est[:3, :3].T + T_est[:3, 3]
    moved_gt = points @ T_gt[:3, :3].T + T_gt[:3, 3]
    distances, _ = cKDTree(moved_est).query(moved_gt, k=1)
    return float(distances.mean())


def _symmetry_stack(symmetries: Symmetries | np.ndarray | None, step_rad: float) -> np.ndarray:
    if symmetries is None:
        return np.eye(4)[None]
    if isinstance(symmetries, Symmetries):
        return symmetries.transforms(step_rad=step_rad)
    stack = np.asarray(symmetries, dtype=np.float64)
    if stack.ndim != 3 or stack.shape[1:] != (4, 4):
        raise ValueError(f'symmetry transforms must be (K, 4, 4), got {stack.shape}')
    return stack


def mssd(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray,
         symmetries: Symmetries | np.ndarray | None = None, *,
         step_rad: float = np.radians(1.0)) -> float:
    """MSSD [BOP20]: ``min_S max_x ||T_est x - T_gt S x||``, metres.

    Args:
        T_est, T_gt: (4, 4) poses in metres.
        points: (N, 3) model points in metres (BOP uses the model vertices).
        symmetries: :class:`Symmetries` or a (K, 4, 4) stack of symmetry transforms.
        step_rad: discretisation of continuous symmetries (BOP uses 0.01 rad per half turn).
    """
    points = _check_points(points)
    T_est, T_gt = _check_pose(T_est, 'T_est'), _check_pose(T_gt, 'T_gt')
    stack = T_gt[None] @ _symmetry_stack(symmetries, step_rad)
    moved_est = points @ T_est[:3, :3].T + T_est[:3, 3]
    best = np.inf
    for chunk in np.array_split(stack, max(1, len(stack) // 64)):
        moved_gt = np.einsum('kij,nj->kni', chunk[:, :3, :3], points) + chunk[:, None, :3, 3]
        best = min(best, float(np.linalg.norm(moved_gt - moved_est[None], axis=-1)
                               .max(axis=1).min()))
    return best


def mspd(T_est: np.ndarray, T_gt: np.ndarray, points: np.ndarray, K: np.ndarray,
         symmetries: Symmetries | np.ndarray | None = None, *,
         step_rad: float = np.radians(1.0)) -> float:
    """MSPD [BOP20]: ``min_S max_x ||pi(T_est x) - pi(T_gt S x)||``, pixels.

    Compare with :data:`BOP19_MSPD_THRESHOLDS_PX` × (image width / 640).

    Args:
        K: (3, 3) camera matrix; the rest as :func:`mssd`.
    """
    points = _check_points(points)
    T_est, T_gt = _check_pose(T_est, 'T_est'), _check_pose(T_gt, 'T_gt')
    stack = T_gt[None] @ _symmetry_stack(symmetries, step_rad)
    K = np.asarray(K, dtype=np.float64)
    proj_est = project_points(points @ T_est[:3, :3].T + T_est[:3, 3], K)
    best = np.inf
    for S in stack:
        proj_gt = project_points(points @ S[:3, :3].T + S[:3, 3], K)
        best = min(best, float(np.linalg.norm(proj_gt - proj_est, axis=1).max()))
    return best


# ------------------------------------------------------------------------------------------------
# VSD


class ModelDepthRenderer:
    """Depth of one model rendered alone (no occluders), cropped to where it projects.

    Args:
        vertices: (V, 3) model vertices in metres.
        faces: (F, 3) int triangle indices.
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.vertices = _check_points(vertices)
        self._renderer = MeshRenderer()
        self._renderer.add_mesh(self.vertices, faces)
        corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)])
        lo, hi = self.vertices.min(0), self.vertices.max(0)
        self._corners = lo + corners * (hi - lo)

    def box(self, intrinsics: CameraIntrinsics, T_camera_object: np.ndarray,
            ) -> tuple[int, int, int, int] | None:
        """Pixel window ``(x0, y0, x1, y1)`` (exclusive) that holds the projection, or None."""
        corners = self._corners @ T_camera_object[:3, :3].T + T_camera_object[:3, 3]
        if np.any(corners[:, 2] <= 1e-6):
            return 0, 0, intrinsics.width, intrinsics.height  # straddles the camera plane
        uv = project_points(corners, intrinsics.K)
        x0 = max(0, int(np.floor(uv[:, 0].min())) - 1)
        y0 = max(0, int(np.floor(uv[:, 1].min())) - 1)
        x1 = min(intrinsics.width, int(np.ceil(uv[:, 0].max())) + 2)
        y1 = min(intrinsics.height, int(np.ceil(uv[:, 1].max())) + 2)
        return (x0, y0, x1, y1) if x1 > x0 and y1 > y0 else None

    def depth(self, intrinsics: CameraIntrinsics, T_camera_object: np.ndarray,
              window: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """(h, w) float32 depth in metres (0 = no surface) inside ``window`` (default: full)."""
        T_camera_object = _check_pose(T_camera_object, 'T_camera_object')
        x0, y0, x1, y1 = window or (0, 0, intrinsics.width, intrinsics.height)
        K = intrinsics.K.copy()
        K[0, 2] -= x0
        K[1, 2] -= y0
        sub = CameraIntrinsics(width=x1 - x0, height=y1 - y0, K=K)
        # the object frame plays the world: the camera sits at T_object_camera
        return self._renderer.render(sub, invert_transform(T_camera_object)).depth_m


def _distance_image(depth: np.ndarray, K: np.ndarray, x0: int, y0: int) -> np.ndarray:
    """Depth (z) to distance along the viewing ray, for a window starting at (x0, y0)."""
    h, w = depth.shape
    u, v = np.meshgrid(np.arange(x0, x0 + w), np.arange(y0, y0 + h))
    scale = np.sqrt(((u - K[0, 2]) / K[0, 0]) ** 2 + ((v - K[1, 2]) / K[1, 1]) ** 2 + 1.0)
    return cast(np.ndarray, depth * scale)


def _visible(dist_test: np.ndarray, dist_model: np.ndarray, delta: float,
             mode: str) -> np.ndarray:
    diff = dist_model - dist_test
    if mode == 'bop18':
        return cast(np.ndarray, (diff <= delta) & (dist_test > 0) & (dist_model > 0))
    return cast(np.ndarray, ((diff <= delta) | (dist_test == 0)) & (dist_model > 0))


def vsd_from_depth(depth_est: np.ndarray, depth_gt: np.ndarray, depth_test: np.ndarray,
                   K: np.ndarray, *, taus_m: tuple[float, ...] | np.ndarray = (0.020,),
                   delta_m: float = 0.015, visib_mode: str = 'bop18',
                   offset: tuple[int, int] = (0, 0)) -> np.ndarray:
    """VSD [BOP18, BOP20] from depth images of the model alone and the measured scene.

    ``e = (sum over V_est & V_gt of [|D_est - D_gt| >= tau] + |V_est ^ V_gt|) / |V_est | V_gt|``
    on distance images (depth converted to distance along the ray); visibility masks use the
    tolerance delta (``visib_mode`` 'bop18': test depth must be valid; 'bop19': missing test
    depth counts as visible). e = 1 when both masks are empty.

    Args:
        depth_est, depth_gt: (H, W) depth of the model rendered alone at the estimated and GT
            pose, metres, 0 = no surface.
        depth_test: (H, W) measured depth of the scene, metres, 0 or NaN = missing.
        K: (3, 3) camera matrix of the full image.
        taus_m: misalignment tolerances in metres (BOP'18: 20 mm).
        delta_m: visibility tolerance in metres (15 mm).
        visib_mode: 'bop18' or 'bop19'.
        offset: (x0, y0) of the window the three images were cut from.

    Returns:
        (len(taus_m),) float64 errors in [0, 1].
    """
    if visib_mode not in ('bop18', 'bop19'):
        raise ValueError(f"visib_mode must be 'bop18' or 'bop19', got {visib_mode!r}")
    if not (depth_est.shape == depth_gt.shape == depth_test.shape):
        raise ValueError('depth_est, depth_gt and depth_test must have the same shape, got '
                         f'{depth_est.shape}, {depth_gt.shape}, {depth_test.shape}')
    K = np.asarray(K, dtype=np.float64)
    test = np.nan_to_num(np.asarray(depth_test, dtype=np.float64), nan=0.0)
    x0, y0 = offset
    dist_test = _distance_image(test, K, x0, y0)
    dist_gt = _distance_image(np.asarray(depth_gt, np.float64), K, x0, y0)
    dist_est = _distance_image(np.asarray(depth_est, np.float64), K, x0, y0)
    visib_gt = _visible(dist_test, dist_gt, delta_m, visib_mode)
    visib_est = _visible(dist_test, dist_est, delta_m, visib_mode) | (visib_gt & (dist_est > 0))
    inter = visib_gt & visib_est
    union_count = int((visib_gt | visib_est).sum())
    taus = np.atleast_1d(np.asarray(taus_m, dtype=np.float64))
    if union_count == 0:
        return np.ones(len(taus))
    outside = union_count - int(inter.sum())
    dists = np.abs(dist_gt[inter] - dist_est[inter])
    return np.array([(np.count_nonzero(dists >= tau) + outside) / union_count for tau in taus])


def vsd(T_est: np.ndarray, T_gt: np.ndarray, depth_test_m: np.ndarray,
        intrinsics: CameraIntrinsics, renderer: ModelDepthRenderer, *,
        taus_m: tuple[float, ...] | np.ndarray = (0.020,), delta_m: float = 0.015,
        visib_mode: str = 'bop18') -> np.ndarray:
    """VSD error of an estimated pose (renders the model; see :func:`vsd_from_depth`).

    Defaults are BOP'18 (tau = 20 mm, delta = 15 mm); for BOP'19 pass
    ``taus_m=BOP19_THRESHOLDS * diameter`` and ``visib_mode='bop19'``. Only the window where
    either pose projects is rendered.

    Args:
        T_est, T_gt: (4, 4) ``T_camera_object`` poses in metres.
        depth_test_m: (H, W) measured depth, metres, 0 or NaN = missing.
        intrinsics: the camera of ``depth_test_m``.
        renderer: the model, as a :class:`ModelDepthRenderer`.

    Returns:
        (len(taus_m),) float64 errors in [0, 1].
    """
    depth_test_m = np.asarray(depth_test_m)
    if depth_test_m.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f'depth_test_m has shape {depth_test_m.shape}, the camera is '
                         f'{intrinsics.height}x{intrinsics.width}')
    boxes = [b for b in (renderer.box(intrinsics, T_est), renderer.box(intrinsics, T_gt)) if b]
    if not boxes:
        return np.ones(len(np.atleast_1d(taus_m)))
    window = (min(b[0] for b in boxes), min(b[1] for b in boxes),
              max(b[2] for b in boxes), max(b[3] for b in boxes))
    x0, y0, x1, y1 = window
    depth_est = renderer.depth(intrinsics, T_est, window)
    depth_gt = renderer.depth(intrinsics, T_gt, window)
    return vsd_from_depth(depth_est, depth_gt, depth_test_m[y0:y1, x0:x1], intrinsics.K,
                          taus_m=taus_m, delta_m=delta_m, visib_mode=visib_mode,
                          offset=(x0, y0))


# ------------------------------------------------------------------------------------------------
# Boxes and recalls


def box_iou(box_a: tuple[float, float, float, float],
            box_b: tuple[float, float, float, float]) -> float:
    """Intersection over union of two boxes given as BOP ``(x, y, width, height)`` in pixels."""
    ax, ay, aw, ah = (float(v) for v in box_a)
    bx, by, bw, bh = (float(v) for v in box_b)
    if aw < 0 or ah < 0 or bw < 0 or bh < 0:
        raise ValueError('box width and height must be non-negative')
    iw = max(0.0, min(ax + aw, bx + bw) - max(ax, bx))
    ih = max(0.0, min(ay + ah, by + bh) - max(ay, by))
    inter = iw * ih
    union = aw * ah + bw * bh - inter
    return inter / union if union > 0 else 0.0


def recall(errors: np.ndarray, threshold: float, *, strict: bool = True) -> float:
    """Share of errors below ``threshold`` (``<`` when strict, as BOP); NaN counts as a miss.

    Returns NaN for an empty input.
    """
    errors = np.asarray(errors, dtype=np.float64)
    if errors.size == 0:
        return float('nan')
    ok = errors < threshold if strict else errors <= threshold
    return float(np.count_nonzero(ok & np.isfinite(errors)) / errors.size)


def average_recall(errors: np.ndarray, thresholds: np.ndarray) -> float:
    """BOP'19 Average Recall: the mean of :func:`recall` over the thresholds."""
    return float(np.mean([recall(errors, t) for t in np.asarray(thresholds)]))


# Two T-LESS parts lying on a table cannot have model origins (their bounding-box centres)
# this close: the smallest part is about 4 cm across.
DUPLICATE_RADIUS_M = 0.03


def duplicate_radius_m(extents_m: np.ndarray) -> float:
    """How close two poses of a part with these bounding-box extents (3,) metres must lie to be
    one part reported twice: half its middle extent, at most :data:`DUPLICATE_RADIUS_M`.

    Two distinct parts lying side by side keep their origins (near the bounding-box centre)
    about a width apart; the middle extent rather than the thinnest leaves room for the few
    millimetres by which two fits of one thin part differ (only parts stacked or standing
    face to face come closer)."""
    middle = float(np.median(np.asarray(extents_m, np.float64)))
    return min(DUPLICATE_RADIUS_M, 0.5 * middle) if middle > 0 else DUPLICATE_RADIUS_M


def count_duplicates(positions_m: np.ndarray, *,
                     radius_m: float | np.ndarray = DUPLICATE_RADIUS_M) -> int:
    """How many of one frame's poses repeat another: one part reported more than once.

    Poses whose translations lie within ``radius_m`` of each other (single linkage) count as
    one part; the count is the number of poses minus the number of such groups. Classes are
    ignored on purpose: a part published as obj_08 and again as obj_22 is still one part.

    Args:
        positions_m: (N, 3) translations of the frame's poses in one frame of reference
            (distances do not depend on which), metres.
        radius_m: one radius, or (N,) one per pose (e.g. :func:`duplicate_radius_m` of its
            part); two poses are near when closer than the smaller of their radii.
    """
    points = np.asarray(positions_m, np.float64).reshape(-1, 3)
    if len(points) < 2:
        return 0
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial.distance import cdist

    radii = np.broadcast_to(np.asarray(radius_m, np.float64), (len(points),))
    near = cdist(points, points) < np.minimum(radii[:, None], radii[None, :])
    groups, _ = connected_components(near, directed=False)
    return int(len(points) - groups)
