"""Point-cloud pre-processing for pose estimation (paper §3.3).

RGB-D to cloud, box crop, the paper's background subtraction (stored background cloud added to the
scene, planes removed with RANSAC, background dropped), statistical outlier removal (k = 50, run
after the voxel grid, on fewer points: algo-notes §B.1, docs/bench/code-figures.md), the ROI cloud
of an instance mask on depth aligned to colour, voxel downsampling, normals oriented towards the
camera and FPFH descriptors (Rusu et al. 2009).

Points are (N, 3) arrays in metres in the frame of the depth image (optical frame: x right, y
down, z forward) unless a function says otherwise. Open3D is used internally; inputs and outputs
are numpy arrays.

References:
    R. B. Rusu, "Semantic 3D Object Maps for Everyday Manipulation in Human Living
    Environments", PhD thesis, TU München, 2009 (statistical outlier removal, normals).
    R. B. Rusu, N. Blodow, M. Beetz, "Fast Point Feature Histograms (FPFH) for 3D
    Registration", ICRA 2009.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from tlessbot_ros.core.common import CameraIntrinsics, depth_to_points, transform_points


@dataclass(frozen=True)
class CloudParams:
    """Pre-processing parameters.

    Attributes:
        sor_neighbors: neighbours of the statistical outlier removal (paper: k = 50).
        sor_std_ratio: points whose mean neighbour distance exceeds mean + ratio * std go.
        plane_distance_m: RANSAC inlier distance of the plane removal.
        plane_iterations: RANSAC iterations per plane.
        max_planes: planes removed at most by :func:`subtract_background`.
        min_plane_fraction: a plane is removed only if it holds at least this fraction of the
            (scene + background) points; smaller planes are object faces.
        background_distance_m: scene points closer than this to a background point are dropped.
        normal_radius_voxels: normal search radius in voxels (algo-notes §C.3: 2).
        normal_max_nn: neighbour cap of the normal estimate.
    """

    sor_neighbors: int = 50
    sor_std_ratio: float = 2.0
    plane_distance_m: float = 0.003
    plane_iterations: int = 200
    max_planes: int = 2
    min_plane_fraction: float = 0.2
    background_distance_m: float = 0.004
    normal_radius_voxels: float = 2.0
    normal_max_nn: int = 30

    def __post_init__(self) -> None:
        if self.sor_neighbors < 1:
            raise ValueError(f'sor_neighbors must be >= 1, got {self.sor_neighbors}')
        if self.plane_distance_m <= 0 or self.background_distance_m < 0:
            raise ValueError('plane_distance_m must be > 0 and background_distance_m >= 0')
        if not 0.0 < self.min_plane_fraction <= 1.0:
            raise ValueError(
                f'min_plane_fraction must be in (0, 1], got {self.min_plane_fraction}')


def _check_points(points: np.ndarray, name: str = 'points') -> np.ndarray:
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f'{name} must be an (N, 3) array, got shape {points.shape}')
    return points


def to_o3d(points: np.ndarray, normals: np.ndarray | None = None) -> o3d.geometry.PointCloud:
    """Open3D cloud of (N, 3) points (and optional (N, 3) normals)."""
    cloud = o3d.geometry.PointCloud(
        o3d.utility.Vector3dVector(np.asarray(_check_points(points), dtype=np.float64)))
    if normals is not None:
        cloud.normals = o3d.utility.Vector3dVector(
            np.asarray(_check_points(normals, 'normals'), dtype=np.float64))
    return cloud


def rgbd_to_cloud(depth_m: np.ndarray, intrinsics: CameraIntrinsics, *,
                  rgb: np.ndarray | None = None, mask: np.ndarray | None = None,
                  box: tuple[int, int, int, int] | None = None
                  ) -> tuple[np.ndarray, np.ndarray | None]:
    """Back-project an aligned RGB-D pair.

    Args:
        depth_m: (H, W) float depth in metres along the optical axis; 0 / NaN = invalid. Convert
            16UC1 millimetre images first (``depth_mm * 1e-3``).
        intrinsics: intrinsics of the colour stream the depth is aligned to.
        rgb: optional (H, W, 3) uint8 colour image aligned with the depth.
        mask: optional (H, W) bool; only these pixels are used.
        box: the (x, y, w, h) box of ``mask``'s pixels when the caller knows it
            (:func:`~tlessbot_ros.core.common.depth_to_points`).

    Returns:
        points (N, 3) float32 in metres (camera optical frame) and colours (N, 3) float32 in
        [0, 1] (None without ``rgb``).
    """
    depth_m = np.asarray(depth_m)
    if depth_m.shape != (intrinsics.height, intrinsics.width):
        raise ValueError(f'depth shape {depth_m.shape} does not match the intrinsics '
                         f'({intrinsics.height}, {intrinsics.width})')
    points, pixels = depth_to_points(depth_m, intrinsics.K, mask=mask, box=box)
    colors = None
    if rgb is not None:
        rgb = np.asarray(rgb)
        if rgb.shape[:2] != depth_m.shape or rgb.ndim != 3:
            raise ValueError(f'rgb must be (H, W, 3) like the depth, got shape {rgb.shape}')
        colors = rgb[pixels[:, 0], pixels[:, 1], :3].astype(np.float32) / 255.0
    return points, colors


def roi_cloud(depth_m: np.ndarray, mask: np.ndarray, intrinsics: CameraIntrinsics, *,
              box: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """(N, 3) float32 points of one instance mask on depth aligned to colour (no pixel offset).

    Args:
        depth_m: (H, W) depth in metres, 0 / NaN invalid.
        mask: (H, W) bool instance mask in the colour image.
        intrinsics: colour intrinsics.
        box: the mask's (x, y, w, h) box when the caller knows it (saves a pass over the
            image); it must hold every pixel of the mask.
    """
    mask = np.asarray(mask)
    if mask.shape != np.shape(depth_m):
        raise ValueError(f'mask shape {mask.shape} differs from depth shape {np.shape(depth_m)}')
    return rgbd_to_cloud(depth_m, intrinsics, mask=mask.astype(bool), box=box)[0]


def steep_pixels(depth_m: np.ndarray, focal_px: float, max_angle_deg: float) -> np.ndarray:
    """(H, W) bool: pixels whose surface turns more than ``max_angle_deg`` from facing the
    camera, by the depth slope between their neighbours (central differences; a pixel next to
    an invalid one counts as steep).

    A stereo depth camera smooths a depth step into a ramp of a few pixels (the RealSense
    D4xx after its spatial filter), and those pixels lie between the part and the table: on no
    surface. Surfaces seen that obliquely are measured worst too.

    Args:
        depth_m: (H, W) depth in metres, 0 / NaN invalid.
        focal_px: the focal length, pixels (one pixel spans depth / focal_px metres).
        max_angle_deg: 0..90; at 90 nothing is steep but the pixels next to invalid ones.
    """
    z = np.where(np.isfinite(depth_m) & (depth_m > 0), depth_m, np.nan).astype(np.float32)
    gx = np.zeros_like(z)
    gy = np.zeros_like(z)
    gx[:, 1:-1] = 0.5 * (z[:, 2:] - z[:, :-2])
    gy[1:-1] = 0.5 * (z[2:] - z[:-2])
    # slope = |grad z| per pixel / (z / f) = tan of the angle between surface and image plane
    slope = np.hypot(gx, gy) * np.float32(focal_px) / z
    with np.errstate(invalid='ignore'):
        gentle: np.ndarray = slope <= np.tan(np.radians(min(max_angle_deg, 89.999)))
    return ~gentle


def drop_steep(mask: np.ndarray, depth_m: np.ndarray, box: tuple[int, int, int, int],
               focal_px: float, max_angle_deg: float) -> np.ndarray:
    """``mask`` (H, W) without its :func:`steep_pixels` (a copy; ``mask`` itself when
    ``max_angle_deg`` is 0: off), looked for in ``box`` (x, y, w, h), which holds the mask."""
    if max_angle_deg <= 0:
        return mask
    x, y, w, h = box
    y0, x0 = max(y - 1, 0), max(x - 1, 0)
    steep = steep_pixels(depth_m[y0:y + h + 1, x0:x + w + 1], focal_px, max_angle_deg)
    mask = np.array(mask, bool)
    mask[y:y + h, x:x + w] &= ~steep[y - y0:y - y0 + h, x - x0:x - x0 + w]
    return mask


def crop_box(points: np.ndarray, min_bound: np.ndarray, max_bound: np.ndarray, *,
             T_box_points: np.ndarray | None = None) -> np.ndarray:
    """Boolean (N,) mask of the points inside an axis-aligned box.

    Args:
        points: (N, 3) points.
        min_bound, max_bound: (3,) box corners in metres, in the box frame.
        T_box_points: optional (4, 4) transform from the points' frame into the box frame (for
            example ``T_world_camera`` to crop the work area above the table).
    """
    points = _check_points(points)
    lo, hi = np.asarray(min_bound, float), np.asarray(max_bound, float)
    if lo.shape != (3,) or hi.shape != (3,) or np.any(hi < lo):
        raise ValueError(f'box bounds must be (3,) with max >= min, got {lo} and {hi}')
    if T_box_points is not None:
        points = transform_points(T_box_points, points)
    return cast(np.ndarray, np.all((points >= lo) & (points <= hi), axis=1))


def voxel_downsample(points: np.ndarray, voxel_size_m: float,
                     normals: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Voxel-grid downsampling (centroid per occupied voxel).

    Returns (M, 3) float64 points and, when given, their averaged (M, 3) normals (not
    renormalised by Open3D; they are renormalised here).
    """
    if voxel_size_m <= 0:
        raise ValueError(f'voxel_size_m must be > 0, got {voxel_size_m}')
    cloud = to_o3d(points, normals).voxel_down_sample(voxel_size=float(voxel_size_m))
    out = np.asarray(cloud.points)
    if normals is None:
        return out, None
    n = np.asarray(cloud.normals)
    n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return out, n


def remove_statistical_outliers(points: np.ndarray, *, neighbors: int = 50,
                                std_ratio: float = 2.0) -> np.ndarray:
    """Boolean (N,) mask of the inliers of the statistical outlier removal (Rusu 2009).

    A point is an outlier when its mean distance to its ``neighbors`` nearest neighbours exceeds
    the global mean by more than ``std_ratio`` standard deviations. Run it after voxelisation.
    The kept points are exactly those of Open3D's ``remove_statistical_outlier`` (its
    arithmetic, in numba: :mod:`~tlessbot_ros.core.pose.outlier_kernels`).

    Args:
        points: (N, 3) points in metres.
        neighbors: k (the point itself counts as one, as in Open3D).
        std_ratio: the threshold is the mean of the points' mean distances plus this many
            standard deviations.
    """
    points = _check_points(points)
    if neighbors < 1 or not std_ratio > 0:
        raise ValueError(f'neighbors must be >= 1 and std_ratio > 0, got {neighbors} and '
                         f'{std_ratio}')
    if len(points) <= neighbors:
        return np.ones(len(points), bool)  # too few points for the statistic: keep everything
    points = np.ascontiguousarray(points, dtype=np.float64)
    if not np.isfinite(points).all():   # the kernels' scan order needs finite coordinates
        keep = np.zeros(len(points), bool)
        _, index = to_o3d(points).remove_statistical_outlier(nb_neighbors=int(neighbors),
                                                             std_ratio=float(std_ratio))
        keep[np.asarray(index, dtype=np.int64)] = True
        return keep
    # Open3D's statistic with its arithmetic, without its KD-tree and cloud (the same kept
    # points: :mod:`~tlessbot_ros.core.pose.outlier_kernels`)
    from tlessbot_ros.core.pose.outlier_kernels import (
        keep_below_threshold,
        mean_neighbour_distances,
    )

    return keep_below_threshold(mean_neighbour_distances(points, int(neighbors)),
                                float(std_ratio))


def estimate_normals(points: np.ndarray, *, radius_m: float, max_nn: int = 30,
                     viewpoint: np.ndarray | None = None) -> np.ndarray:
    """(N, 3) float64 unit normals from the k-nearest-neighbour covariance, facing ``viewpoint``.

    Args:
        points: (N, 3) points in metres.
        radius_m: hybrid search radius (algo-notes §C.3: 2 voxels).
        max_nn: neighbour cap.
        viewpoint: (3,) camera centre in the points' frame (default: the origin, i.e. points in
            the camera's optical frame).
    """
    if radius_m <= 0:
        raise ValueError(f'radius_m must be > 0, got {radius_m}')
    cloud = to_o3d(points)
    cloud.estimate_normals(search_param=o3d.geometry.KDTreeSearchParamHybrid(
        radius=float(radius_m), max_nn=int(max_nn)))
    normals: np.ndarray = np.asarray(cloud.normals).copy()
    view = np.zeros(3) if viewpoint is None else np.asarray(viewpoint, float)
    flip = np.sum(normals * (view - np.asarray(points, float)), axis=1) < 0
    normals[flip] *= -1.0
    return normals


def fit_plane(points: np.ndarray, *, distance_m: float = 0.003, iterations: int = 200,
              seed: int | None = 0) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC plane (Fischler and Bolles 1981) through point triples drawn with ``seed``.

    Open3D's ``segment_plane``, taken in turn: triples are scored in the order drawn (more
    inliers closer than ``distance_m``, then a lower RMS distance, beats the best so far), and
    the search stops once the best's inlier share makes a better triple unlikely
    (:data:`PLANE_CONFIDENCE`). Taken in turn, not on threads that draw triples in the order
    they ask, so the answer is a function of the points and the seed alone.

    Args:
        points: (N, 3) points, N >= 3, metres.
        distance_m: inlier distance from the plane.
        iterations: triples drawn at most.
        seed: the generator's seed (None: fresh entropy, a different draw per call).

    Returns:
        (4,) plane ``a, b, c, d`` with unit normal (``ax + by + cz + d = 0``), fitted by least
        squares to the best triple's inliers; (N,) bool mask of those inliers (all False and a
        zero plane when every triple is degenerate).
    """
    points = np.asarray(_check_points(points), np.float64)
    if len(points) < 3:
        raise ValueError(f'need at least 3 points to fit a plane, got {len(points)}')
    triples = _distinct_triples(np.random.default_rng(seed), len(points), int(iterations))
    a, b, c = (points[triples[:, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    length = np.linalg.norm(normals, axis=1)
    valid = length > 1e-12   # three points on a line: no plane, not counted as a try
    normals = normals[valid] / length[valid, None]
    offsets = -np.einsum('ij,ij->i', normals, a[valid])
    search = _PlaneSearch(len(points), len(normals))
    # blocks of triples: the search usually stops within the first few dozen
    block = max(1, min(32, 2_000_000 // len(points)))
    for start in range(0, len(normals), block):
        distance = np.abs(normals[start:start + block] @ points.T
                          + offsets[start:start + block, None])
        inside = distance < distance_m
        if search.take(inside.sum(axis=1), np.where(inside, distance ** 2, 0.0).sum(axis=1)):
            break
    best = search.best
    if best < 0:
        return np.zeros(4), np.zeros(len(points), bool)
    inliers = np.abs(points @ normals[best] + offsets[best]) < distance_m
    return _least_squares_plane(points[inliers], normals[best]), inliers


PLANE_CONFIDENCE = 0.99999999
"""Open3D's ``segment_plane`` default: the search stops after ``log(1 - c) / log(1 - w^3)``
triples, ``w`` the best inlier share so far."""


class _PlaneSearch:
    """The best of the triples taken in turn (inlier count, then the RMS of the inliers'
    distances) up to the confidence stop; ``best`` -1: none has an inlier yet."""

    def __init__(self, n_points: int, n_triples: int) -> None:
        self.n_points, self.tried, self.stop = n_points, 0, float(n_triples)
        self.best, self.count, self.rms = -1, 0, 0.0

    def take(self, count: np.ndarray, squares: np.ndarray) -> bool:
        """The next triples' inlier counts and summed squared distances; True: stop."""
        for k in range(len(count)):
            if self.tried > self.stop:
                return True
            rms = float(np.sqrt(squares[k] / max(int(count[k]), 1)))
            if count[k] > self.count or count[k] == self.count > 0 and rms < self.rms:
                self.best, self.count, self.rms = self.tried, int(count[k]), rms
                share = self.count / self.n_points
                self.stop = 0.0 if share >= 1.0 else min(
                    np.log1p(-PLANE_CONFIDENCE) / np.log1p(-share ** 3), self.stop)
            self.tried += 1
        return self.tried > self.stop


def _distinct_triples(rng: np.random.Generator, n: int, count: int) -> np.ndarray:
    """(count, 3) int64 indices into ``n`` points, three distinct ones a row, each triple
    uniform over the n (n - 1) (n - 2) ordered choices."""
    first = rng.integers(0, n, count)
    second = rng.integers(0, n - 1, count)
    second += second >= first
    third = rng.integers(0, n - 2, count)
    low, high = np.minimum(first, second), np.maximum(first, second)
    third += third >= low
    third += third >= high
    return np.stack([first, second, third], axis=1)


def _least_squares_plane(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(4,) the plane through the centroid of (M, 3) ``points`` normal to their direction of
    least spread, its normal on the side of ``normal``."""
    centre = points.mean(axis=0)
    centred = points - centre
    _, vectors = np.linalg.eigh(centred.T @ centred)   # eigenvalues ascending
    fitted = vectors[:, 0] if len(points) >= 3 else normal
    fitted = fitted if float(fitted @ normal) >= 0 else -fitted
    return np.array([*fitted, -float(fitted @ centre)])


def subtract_background(scene: np.ndarray, background: np.ndarray, *,
                        params: CloudParams = CloudParams(), seed: int | None = 0) -> np.ndarray:
    """The paper's background subtraction; returns the (N,) bool mask of scene foreground points.

    The stored background cloud (the empty table) is added to the scene cloud, so the table
    plane dominates the RANSAC plane fits even where objects hide it; up to
    ``params.max_planes`` large planes are removed, then every scene point close to a
    background point is dropped, and what remains of the scene is the foreground.

    Args:
        scene: (N, 3) scene points in metres.
        background: (M, 3) background points in the same frame (captured without objects).
    """
    scene = _check_points(scene, 'scene')
    background = _check_points(background, 'background')
    merged = np.concatenate([scene, background]).astype(np.float64)
    alive = np.ones(len(merged), bool)
    for _ in range(params.max_planes):
        index = np.flatnonzero(alive)
        if len(index) < 3:
            break
        _, inliers = fit_plane(merged[index], distance_m=params.plane_distance_m,
                               iterations=params.plane_iterations, seed=seed)
        if inliers.sum() < params.min_plane_fraction * len(merged):
            break
        alive[index[inliers]] = False
    keep = alive[:len(scene)]
    if len(background) and params.background_distance_m > 0 and keep.any():
        candidates = np.flatnonzero(keep)
        distance, _ = cKDTree(background).query(
            scene[candidates], k=1, distance_upper_bound=params.background_distance_m)
        keep[candidates[np.isfinite(distance)]] = False
    return keep


def preprocess_roi(points: np.ndarray, *, voxel_size_m: float,
                   params: CloudParams = CloudParams(),
                   viewpoint: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """ROI cloud -> voxel grid -> statistical outlier removal -> normals facing the camera.

    Args:
        points: (N, 3) ROI points in the camera frame, metres.
        voxel_size_m: voxel edge; normals use ``params.normal_radius_voxels`` voxels.
        viewpoint: camera centre in the points' frame (default origin).

    Returns:
        points (M, 3) float64 and unit normals (M, 3) float64.
    """
    down, _ = voxel_downsample(points, voxel_size_m)
    down = down[remove_statistical_outliers(down, neighbors=params.sor_neighbors,
                                            std_ratio=params.sor_std_ratio)]
    if len(down) == 0:
        return down, down.copy()
    normals = estimate_normals(down, radius_m=params.normal_radius_voxels * voxel_size_m,
                               max_nn=params.normal_max_nn, viewpoint=viewpoint)
    return down, normals


def compute_fpfh(points: np.ndarray, normals: np.ndarray, *, radius_m: float,
                 max_nn: int = 100) -> np.ndarray:
    """(N, 33) float32 FPFH descriptors of a cloud with normals (Rusu et al. 2009)."""
    if radius_m <= 0:
        raise ValueError(f'radius_m must be > 0, got {radius_m}')
    # (Open3D's stub lists ``indices`` as required; the binding has it optional)
    feature = o3d.pipelines.registration.compute_fpfh_feature(  # type: ignore[call-arg]
        to_o3d(points, normals),
        search_param=o3d.geometry.KDTreeSearchParamHybrid(radius=float(radius_m),
                                                          max_nn=int(max_nn)))
    return cast(np.ndarray, np.asarray(feature.data, dtype=np.float32).T.copy())
