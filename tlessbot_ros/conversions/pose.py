"""geometry_msgs/PoseStamped <-> (4, 4) transform + frame + stamp."""
from __future__ import annotations

from typing import Any

import numpy as np

from tlessbot_ros.conversions.messages import (
    MessageFactory,
    default_factory,
    make_header,
    stamp_to_ns,
)
from tlessbot_ros.core.common import (
    make_transform,
    matrix_from_quaternion,
    quaternion_from_matrix,
)


def pose_stamped_to_transform(msg: Any) -> tuple[np.ndarray, str, int]:
    """Returns (T_frame_object (4, 4) float64, frame_id, stamp in ns).

    Raises:
        ValueError: a zero-length or non-finite quaternion, or a non-finite position.
    """
    T = pose_to_transform(msg.pose.position, msg.pose.orientation, what='PoseStamped')
    return T, str(msg.header.frame_id), stamp_to_ns(msg.header.stamp)


def pose_to_transform(position: Any, orientation: Any, *, what: str = 'pose') -> np.ndarray:
    """(4, 4) float64 transform of a position (x, y, z fields: Point, Vector3) and a quaternion.

    Raises:
        ValueError: a zero-length or non-finite quaternion, or a non-finite position.
    """
    p, q = position, orientation
    quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
    position = np.array([p.x, p.y, p.z], dtype=np.float64)
    if not (np.isfinite(quat).all() and np.isfinite(position).all()):
        raise ValueError(f'{what} has non-finite values')
    if np.linalg.norm(quat) < 1e-9:
        raise ValueError(f'{what} orientation is a zero quaternion')
    return make_transform(matrix_from_quaternion(quat), position)


def transform_to_pose_stamped(
    T: np.ndarray, *, frame_id: str, stamp_ns: int, factory: MessageFactory | None = None
) -> Any:
    """PoseStamped of a rigid (4, 4) transform (object pose in ``frame_id``)."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ValueError(f'T must be a finite 4x4 transform, got shape {T.shape}')
    factory = factory or default_factory()
    x, y, z, w = quaternion_from_matrix(T[:3, :3])
    tx, ty, tz = (float(v) for v in T[:3, 3])
    return factory.new(
        'geometry_msgs/msg/PoseStamped',
        header=make_header(frame_id, stamp_ns, factory),
        pose=factory.new(
            'geometry_msgs/msg/Pose',
            position=factory.new('geometry_msgs/msg/Point', x=tx, y=ty, z=tz),
            orientation=factory.new('geometry_msgs/msg/Quaternion', x=float(x), y=float(y),
                                    z=float(z), w=float(w)),
        ),
    )


def camera_poses_to_pose_array(poses: dict[str, np.ndarray], *, names: tuple[str, ...],
                               frame_id: str, stamp_ns: int = 0,
                               factory: MessageFactory | None = None) -> Any:
    """geometry_msgs/PoseArray of camera poses (``T_world_camera`` (4, 4) each) in the order
    of ``names`` (the localiser's ``localiser/rig``: top, then side), in ``frame_id``."""
    factory = factory or default_factory()
    messages = [transform_to_pose_stamped(poses[name], frame_id=frame_id, stamp_ns=stamp_ns,
                                          factory=factory).pose for name in names]
    return factory.new('geometry_msgs/msg/PoseArray',
                       header=make_header(frame_id, stamp_ns, factory), poses=messages)


def pose_array_to_camera_poses(msg: Any, *, names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """{name: T_world_camera (4, 4) float64} from a PoseArray written by
    :func:`camera_poses_to_pose_array` with the same ``names``.

    Raises:
        ValueError: not one pose per name, or a pose with non-finite values or a zero
            quaternion.
    """
    poses = list(msg.poses)
    if len(poses) != len(names):
        raise ValueError(f'expected {len(names)} camera poses ({", ".join(names)}), got '
                         f'{len(poses)}')
    out = {}
    for name, pose in zip(names, poses):
        p, q = pose.position, pose.orientation
        quat = np.array([q.x, q.y, q.z, q.w], dtype=np.float64)
        position = np.array([p.x, p.y, p.z], dtype=np.float64)
        if not (np.isfinite(quat).all() and np.isfinite(position).all()) or \
                np.linalg.norm(quat) < 1e-9:
            raise ValueError(f'the pose of camera {name} is not a valid pose')
        out[name] = make_transform(matrix_from_quaternion(quat), position)
    return out
