"""Camera intrinsics, rigid transforms, projection and rotation conversions.

Conventions: SI units (metres, radians). Camera frames are optical frames (REP-103): x right,
y down, z forward. A transform ``T_a_b`` is a (4, 4) float64 matrix mapping points expressed in
frame ``b`` into frame ``a`` (``p_a = T_a_b @ p_b``). Quaternions are (x, y, z, w), as in
geometry_msgs.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np
import numpy.typing as npt


@dataclass(frozen=True)
class RegionOfInterest:
    """The CameraInfo ROI: a sub-window of the full image, in pixels (all zero = full image)."""

    x_offset: int = 0
    y_offset: int = 0
    width: int = 0
    height: int = 0
    do_rectify: bool = False


@dataclass(frozen=True)
class CameraIntrinsics:
    """Pinhole intrinsics of one image stream.

    Attributes:
        width, height: image size in pixels.
        K: (3, 3) float64 camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] in pixels.
        D: (n,) float64 distortion coefficients (plumb_bob: k1, k2, t1, t2, k3).
        distortion_model: 'plumb_bob', 'equidistant' or 'rational_polynomial'.
        roi: the region of interest, see :class:`RegionOfInterest`.
    """

    width: int
    height: int
    K: np.ndarray
    D: np.ndarray = field(default_factory=lambda: np.zeros(5))
    distortion_model: str = 'plumb_bob'
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        if K.shape != (3, 3):
            raise ValueError(f'K must be 3x3, got shape {K.shape}')
        if self.width <= 0 or self.height <= 0:
            raise ValueError(f'image size must be positive, got {self.width}x{self.height}')
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise ValueError(f'focal lengths must be positive, got fx={K[0, 0]} fy={K[1, 1]}')
        object.__setattr__(self, 'K', K)
        object.__setattr__(self, 'D', np.asarray(self.D, dtype=np.float64).ravel())

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @classmethod
    def from_fov(cls, width: int, height: int, hfov_deg: float) -> CameraIntrinsics:
        """Ideal pinhole intrinsics with square pixels and a centred principal point."""
        fx = 0.5 * width / np.tan(np.radians(hfov_deg) / 2.0)
        K = np.array([[fx, 0.0, (width - 1) / 2.0], [0.0, fx, (height - 1) / 2.0], [0, 0, 1]])
        return cls(width=width, height=height, K=K)


def make_transform(R: npt.ArrayLike, t: npt.ArrayLike) -> np.ndarray:
    """(4, 4) homogeneous transform from a (3, 3) rotation and a (3,) translation."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(R, dtype=np.float64).reshape(3, 3)
    T[:3, 3] = np.asarray(t, dtype=np.float64).reshape(3)
    return T


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid (4, 4) transform, using R^T instead of a general matrix inverse."""
    R = T[:3, :3]
    t = T[:3, 3]
    return make_transform(R.T, -R.T @ t)


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a (4, 4) transform to (N, 3) points; returns (N, 3) float64."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return cast(np.ndarray, points @ T[:3, :3].T + T[:3, 3])


def project_points(points_c: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pinhole projection of (N, 3) camera-frame points (metres) to (N, 2) pixel coordinates.

    Pixel centres are at integer coordinates (OpenCV / ROS convention). Points with z <= 0 give
    non-finite coordinates.
    """
    points_c = np.asarray(points_c, dtype=np.float64).reshape(-1, 3)
    with np.errstate(divide='ignore', invalid='ignore'):
        z = np.where(points_c[:, 2] > 0, points_c[:, 2], np.nan)
        u = K[0, 0] * points_c[:, 0] / z + K[0, 2]
        v = K[1, 1] * points_c[:, 1] / z + K[1, 2]
    return np.stack([u, v], axis=1)


def mask_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    """(x, y, w, h) pixel box of the True (non-zero) pixels of a (H, W) mask; (0, 0, 0, 0)
    when it is empty."""
    rows = np.flatnonzero(np.any(mask, axis=1))
    cols = np.flatnonzero(np.any(mask, axis=0))
    if rows.size == 0:
        return 0, 0, 0, 0
    return int(cols[0]), int(rows[0]), int(cols[-1] - cols[0] + 1), int(rows[-1] - rows[0] + 1)


def depth_to_points(
    depth_m: np.ndarray, K: np.ndarray, *, mask: np.ndarray | None = None,
    box: tuple[int, int, int, int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Back-project a depth image into the camera's optical frame.

    Args:
        depth_m: (H, W) depth along the optical axis in metres; 0 or NaN mark invalid pixels.
        K: (3, 3) camera matrix.
        mask: optional (H, W) bool; only pixels where it is True are used.
        box: the (x, y, w, h) box of ``mask``'s pixels when the caller knows it (e.g. from
            :func:`~tlessbot_ros.core.common.label_boxes`); found here otherwise. Pixels of
            the mask outside it are not used.

    Returns:
        points: (N, 3) float32 points in metres, valid pixels only, in row-major pixel order.
        pixels: (N, 2) int64 (row, col) of each point.
    """
    depth_m = np.asarray(depth_m)
    if depth_m.ndim != 2:
        raise ValueError(f'depth must be a 2-D (H, W) array, got shape {depth_m.shape}')
    r0, r1, c0, c1 = 0, depth_m.shape[0], 0, depth_m.shape[1]
    if mask is not None:
        if mask.shape != depth_m.shape:
            raise ValueError(f'mask shape {mask.shape} differs from depth shape {depth_m.shape}')
        mask = mask.astype(bool, copy=False)
        # Work in the mask's bounding box: a part covers a few % of the image.
        c0, r0, w, h = mask_box(mask) if box is None else box
        r1, c1 = r0 + h, c0 + w
    window = depth_m[r0:r1, c0:c1]
    valid = np.isfinite(window) & (window > 0)
    if mask is not None:
        valid &= mask[r0:r1, c0:c1]
    rows, cols = np.nonzero(valid)
    z = window[rows, cols].astype(np.float32)
    rows, cols = rows + r0, cols + c0
    x = (cols.astype(np.float32) - np.float32(K[0, 2])) * z / np.float32(K[0, 0])
    y = (rows.astype(np.float32) - np.float32(K[1, 2])) * z / np.float32(K[1, 1])
    return np.stack([x, y, z], axis=1), np.stack([rows, cols], axis=1)


def quaternion_from_matrix(R: np.ndarray) -> np.ndarray:
    """(x, y, z, w) unit quaternion, w >= 0, of a (3, 3) rotation matrix (Shepperd's method)."""
    R = np.asarray(R, dtype=np.float64)[:3, :3]
    trace = np.trace(R)
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = np.array([(R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s,
                      (R[1, 0] - R[0, 1]) / s, 0.25 * s])
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k])
        q = np.empty(4)
        q[i] = 0.25 * s
        q[j] = (R[j, i] + R[i, j]) / s
        q[k] = (R[k, i] + R[i, k]) / s
        q[3] = (R[k, j] - R[j, k]) / s
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def matrix_from_quaternion(q: np.ndarray) -> np.ndarray:
    """(3, 3) rotation from an (x, y, z, w) quaternion; the quaternion is normalised first."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rpy_from_matrix(R: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw in radians (fixed-axis X, Y, Z; R = Rz(yaw) Ry(pitch) Rx(roll))."""
    R = np.asarray(R, dtype=np.float64)
    pitch = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    if abs(R[2, 0]) < 1.0 - 1e-9:
        roll = np.arctan2(R[2, 1], R[2, 2])
        yaw = np.arctan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: put everything into yaw
        roll = 0.0
        yaw = np.arctan2(-R[0, 1], R[1, 1])
    return np.array([roll, pitch, yaw])


def rotation_about_axis(axis: npt.ArrayLike, angle_rad: float) -> np.ndarray:
    """(3, 3) rotation of ``angle_rad`` about a (3,) axis (Rodrigues)."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    Kx = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    R: np.ndarray = np.eye(3) + np.sin(angle_rad) * Kx + (1 - np.cos(angle_rad)) * (Kx @ Kx)
    return R


def nearest_rotation(R: np.ndarray, *, tolerance: float = 0.05) -> np.ndarray | None:
    """The rotation nearest (Frobenius) to a (3, 3) matrix that is almost one, or None.

    Annotated poses (BOP ground truth, results files) hold matrices a little off SO(3)
    (determinants up to 1.014); angles taken on them are off too. The SVD projection
    ``U diag(1, 1, det(U V^T)) V^T`` is exact for a rotation. ``tolerance``: largest
    ``|R R^T - I|`` entry and ``|det R - 1|`` accepted; beyond it (or a reflection) None.
    """
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    if not np.all(np.isfinite(R)):
        return None
    det = float(np.linalg.det(R))
    if det <= 0 or abs(det - 1.0) > tolerance or np.abs(R @ R.T - np.eye(3)).max() > tolerance:
        return None
    U, _, Vt = np.linalg.svd(R)
    nearest: np.ndarray = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
    return nearest


def rotation_angle_deg(R_a: np.ndarray, R_b: np.ndarray) -> float:
    """Geodesic angle between two rotations, in degrees, in [0, 180]."""
    cos = (np.trace(np.asarray(R_a)[:3, :3].T @ np.asarray(R_b)[:3, :3]) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def look_at(eye: npt.ArrayLike, target: npt.ArrayLike, up: npt.ArrayLike) -> np.ndarray:
    """T_world_camera of an optical-frame camera at ``eye`` looking at ``target``.

    The camera's z axis points at the target and its y axis (image down) points away from
    ``up``, so ``up`` appears at the top of the image.
    """
    position = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - position
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-9:
        raise ValueError('up is parallel to the viewing direction; choose another up vector')
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_transform(np.stack([x, y, z], axis=1), position)


def point_set_diameter(points: np.ndarray) -> float:
    """Largest distance between two of the (N, 3) points, e.g. a model's vertices (BOP's object
    diameter). Computed on the convex hull, in blocks to bound memory."""
    from scipy.spatial import ConvexHull, QhullError

    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    try:
        points = points[ConvexHull(points).vertices]
    except (QhullError, ValueError):  # flat or tiny sets: use every point
        pass
    best = 0.0
    for start in range(0, len(points), 1024):
        block = points[start:start + 1024]
        best = max(best, float(np.max(np.sum((block[:, None] - points[None]) ** 2, axis=-1))))
    return float(np.sqrt(best))
