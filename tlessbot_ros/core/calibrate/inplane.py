"""Rigid motions in the table plane, and a camera levelled onto an observed table.

Two cameras that each see the table know their own tilt and height over it (the plane in their
depth), but not where they stand relative to each other *in* the plane: a turn about the table
normal and a shift along the table. Those three numbers are an in-plane transform

    G = [[cos a, -sin a, 0, x], [sin a, cos a, 0, y], [0, 0, 1, 0], [0, 0, 0, 1]]

(a turn of ``a`` radians about the world z axis through the world origin, then a shift by
``(x, y)`` metres), which keeps heights above the table. :func:`procrustes_2d` is the
least-squares fit of one to point pairs (Arun, Huang & Blostein, IEEE PAMI 1987, restricted to
two dimensions, where the rotation has a closed form).
"""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.common.geometry import make_transform, rotation_about_axis


def inplane_transform(yaw_rad: float, x_m: float, y_m: float) -> np.ndarray:
    """(4, 4) float64: a turn of ``yaw_rad`` about world z, then a shift by (x_m, y_m, 0)."""
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    return make_transform(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]),
                          [x_m, y_m, 0.0])


def inplane_parameters(G: np.ndarray) -> tuple[float, float, float]:
    """(yaw_rad, x_m, y_m) of an in-plane transform (:func:`inplane_transform`)."""
    G = np.asarray(G, np.float64)
    return float(np.arctan2(G[1, 0], G[0, 0])), float(G[0, 3]), float(G[1, 3])


def procrustes_2d(source: np.ndarray, target: np.ndarray,
                  weights: np.ndarray | None = None) -> np.ndarray:
    """The in-plane transform G that best maps ``source`` onto ``target`` (least squares).

    Args:
        source, target: (N, 2) or (N, 3) float points (only x, y are used), N >= 1; with one
            pair the turn is 0 (a shift alone).
        weights: (N,) non-negative weights, or None (all 1).

    Returns:
        (4, 4) float64 in-plane transform (:func:`inplane_transform`).

    Raises:
        ValueError: shapes differ, no pairs, or the weights sum to zero.
    """
    source = np.asarray(source, np.float64)[:, :2]
    target = np.asarray(target, np.float64)[:, :2]
    if source.shape != target.shape or len(source) == 0:
        raise ValueError(f'source and target must be the same (N, 2) shape with N >= 1, got '
                         f'{source.shape} and {target.shape}')
    w = np.ones(len(source)) if weights is None else np.asarray(weights, np.float64)
    if not w.sum() > 0:
        raise ValueError('the weights must not all be zero')
    w = w / w.sum()
    centre_s, centre_t = w @ source, w @ target
    s, t = source - centre_s, target - centre_t
    # sum of w * (s . t) and of w * (s x t): cos and sin of the turn, scaled
    dot = float(np.sum(w * (s[:, 0] * t[:, 0] + s[:, 1] * t[:, 1])))
    cross = float(np.sum(w * (s[:, 0] * t[:, 1] - s[:, 1] * t[:, 0])))
    yaw = float(np.arctan2(cross, dot)) if len(source) > 1 else 0.0
    c, si = np.cos(yaw), np.sin(yaw)
    shift = centre_t - np.array([c * centre_s[0] - si * centre_s[1],
                                 si * centre_s[0] + c * centre_s[1]])
    return inplane_transform(yaw, float(shift[0]), float(shift[1]))


def level_camera_on_plane(T_world_camera: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """A camera pose turned the least, about its own centre, so that the table plane it sees
    becomes world z = 0, and raised or lowered to its height over that plane.

    A bumped camera turns about its mount, not about the middle of the table: turning about
    the camera centre keeps its position in the plane (x, y) and its heading as the prior
    has them, so the in-plane error that is left (:func:`procrustes_2d`) stays as small as the
    bump. (``table_plane.align_frame_to_plane`` turns about the world origin instead, which
    suits a frame used only for heights.)

    Args:
        T_world_camera: (4, 4) the prior pose (e.g. from config/cell.yaml).
        plane: (4,) a, b, c, d of the table in the camera's optical frame, unit normal towards
            the camera (``find_table_plane``); ``d`` is the camera's height over it.

    Returns:
        (4, 4) float64 ``T_world_camera`` whose world z = 0 is the plane, z up.
    """
    T = np.asarray(T_world_camera, np.float64)
    plane = np.asarray(plane, np.float64).reshape(4)
    scale = np.linalg.norm(plane[:3])
    if not scale > 0:
        raise ValueError(f'plane has a zero normal: {plane}')
    normal = T[:3, :3] @ (plane[:3] / scale)   # the table's normal by the prior's rotation
    height = plane[3] / scale
    if height < 0:   # the camera must be above the table: normal towards it
        normal, height = -normal, -height
    axis = np.cross(normal, [0.0, 0.0, 1.0])
    angle = float(np.arctan2(np.linalg.norm(axis), normal[2]))
    if np.linalg.norm(axis) < 1e-12:
        axis = np.array([1.0, 0.0, 0.0])
    R = rotation_about_axis(axis, angle) @ T[:3, :3]
    return make_transform(R, [T[0, 3], T[1, 3], height])
