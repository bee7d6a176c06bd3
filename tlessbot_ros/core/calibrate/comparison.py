"""How far one rig is from another: per camera, and gauge-free (the top -> side transform, the
heights and tilts over the table)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlessbot_ros.core.common.geometry import rotation_angle_deg
from tlessbot_ros.core.common.rig import SIDE, TOP, Rig


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


__all__ = ['RigDifference', 'RigErrors', 'pose_difference', 'rig_differences', 'rig_errors']
