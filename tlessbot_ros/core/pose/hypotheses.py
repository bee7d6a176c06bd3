"""The table path's hypotheses of one stable pose (:mod:`.estimator`): the object resting on
the table at every yaw step, and the rotations they are built from."""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from tlessbot_ros.core.pose.database import CONTINUOUS_YAW_PERIOD, ObjectTemplates


def rodrigues(omega: np.ndarray) -> np.ndarray:
    """Batched (K, 3) rotation vectors -> (K, 3, 3) matrices."""
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = omega / safe[..., 0]
    K = np.zeros(omega.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -k[..., 2], k[..., 1]
    K[..., 1, 0], K[..., 1, 2] = k[..., 2], -k[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -k[..., 1], k[..., 0]
    eye = np.broadcast_to(np.eye(3), K.shape)
    return cast(np.ndarray, eye + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K))


def rotations_about_z(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros(np.shape(yaw) + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


# Half turns about the object's x, y and z axes (the final ICP's flipped starts).
HALF_TURNS = rodrigues(np.pi * np.eye(3))


@dataclass(frozen=True)
class RestingHypotheses:
    """What the table path's hypotheses of one stable pose owe to the object alone (the same
    for every part: made once, :meth:`ObjectTemplates.derived`).

    Attributes:
        Rz: (Y, 3, 3) rotations about the table normal by the yaw hypotheses (0 <= yaw <
            period in ``yaw_step_deg`` steps; yaw 0 alone for a continuous symmetry).
        T_world_object: (Y, 4, 4) the object resting at each yaw, its origin above the world
            origin (the scene's centroid then shifts x and y).
        points, normals: (M, 3) the model subset resting at yaw 0, table frame.
        normal_dot_point: (M,) ``normals . points`` row by row (the back-face test's offset).
    """

    Rz: np.ndarray
    T_world_object: np.ndarray
    points: np.ndarray
    normals: np.ndarray
    normal_dot_point: np.ndarray


def resting_hypotheses(obj: ObjectTemplates, stable: int, yaw_step_deg: float
                        ) -> RestingHypotheses:
    """The :class:`RestingHypotheses` of stable pose ``stable`` (index into ``stable_poses``)
    with yaws ``yaw_step_deg`` apart."""
    period = obj.yaw_periods[stable]
    if period == CONTINUOUS_YAW_PERIOD:
        yaws = np.zeros(1)
    else:
        yaws = np.arange(0.0, period - 1e-9, np.radians(yaw_step_deg))
    Rz = rotations_about_z(yaws)                                                  # (Y, 3, 3)
    T_s = obj.stable_poses[stable]
    model, normals = obj.model_subset()
    points = model @ T_s[:3, :3].T + T_s[:3, 3]                     # resting, yaw 0
    normals = normals @ T_s[:3, :3].T
    T = np.tile(np.eye(4), (len(yaws), 1, 1))
    T[:, :3, :3] = Rz @ T_s[:3, :3]
    T[:, :3, 3] = Rz @ T_s[:3, 3]
    return RestingHypotheses(Rz, T, points, normals, np.sum(normals * points, axis=1))


__all__ = ['HALF_TURNS', 'RestingHypotheses', 'resting_hypotheses', 'rodrigues',
           'rotations_about_z']
