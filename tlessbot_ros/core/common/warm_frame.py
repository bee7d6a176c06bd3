"""A synthetic frame for warming a stage up: a table with one box on it, seen by a camera.

A node runs this through its stage before it reports ready, so that everything a first real
frame would touch (lazy imports, OpenCV and scikit-image first calls, allocator growth) has
happened, and the first real frame costs what the hundredth costs. The frame is analytic
(ray-box and ray-plane intersections), so it needs no renderer and no data file.
"""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.common.geometry import CameraIntrinsics

TABLE_RGB = (200, 196, 188)
BOX_RGB = (120, 110, 95)


def table_with_box(intrinsics: CameraIntrinsics, T_world_camera: np.ndarray, *,
                   box_size_m: tuple[float, float, float] = (0.06, 0.04, 0.03)
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The table plane z = 0 with an axis-aligned box standing at the world origin.

    Args:
        intrinsics: the camera's pinhole model (distortion ignored).
        T_world_camera: (4, 4) pose of the camera's optical frame in the world (z up).
        box_size_m: the box's x, y, z extent in metres.

    Returns:
        rgb: (H, W, 3) uint8, depth_m: (H, W) float32 metres along the optical axis (0 where a
        ray misses the table), box_mask: (H, W) bool pixels that see the box.
    """
    h, w = intrinsics.height, intrinsics.width
    K = np.asarray(intrinsics.K, np.float64)
    v, u = np.mgrid[0:h, 0:w].astype(np.float64)
    rays_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    R, origin = T_world_camera[:3, :3], T_world_camera[:3, 3]
    rays = rays_c @ R.T                        # world direction per pixel, z_c = 1 per unit
    with np.errstate(divide='ignore', invalid='ignore'):
        t_table = np.where(rays[..., 2] < 0, -origin[2] / rays[..., 2], np.inf)
        half = np.asarray(box_size_m, np.float64) / 2.0
        lo = (np.array([-half[0], -half[1], 0.0]) - origin) / rays
        hi = (np.array([half[0], half[1], 2 * half[2]]) - origin) / rays
    t_near = np.nanmax(np.minimum(lo, hi), axis=-1)
    t_far = np.nanmin(np.maximum(lo, hi), axis=-1)
    box = (t_near <= t_far) & (t_near > 0)
    t = np.where(box, t_near, t_table)
    depth = np.where(np.isfinite(t), t, 0.0).astype(np.float32)   # z_c of the ray is 1
    rgb = np.empty((h, w, 3), np.uint8)
    rgb[...] = TABLE_RGB
    rgb[box] = BOX_RGB
    return rgb, depth, box
