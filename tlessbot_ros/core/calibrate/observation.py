"""What one frame gives the scene calibration: per view, its table plane and the part points
above it, grouped into blobs (:func:`observe_view`; its cost: docs/bench/rig-calibration.md)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from tlessbot_ros.core.calibrate.params import SceneCalibrationParams


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

    @classmethod
    def plane_only(cls, plane: np.ndarray) -> ViewObservation:
        """A view that gives its table plane and no part points."""
        return cls(np.asarray(plane, np.float64), np.zeros((0, 3), np.float32),
                   np.zeros(0, np.int32), np.zeros(0, bool))


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



@dataclass(frozen=True)
class FrameObservation:
    """One frame's observations, by view name (only views whose table was found)."""

    views: dict[str, ViewObservation]
    index: int

    def has_parts(self, names: Sequence[str]) -> bool:
        return all(name in self.views and self.views[name].blobs > 0 for name in names)


__all__ = ['FrameObservation', 'ViewObservation', 'observe_view', 'view_stride_px']
