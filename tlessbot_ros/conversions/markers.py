"""visualization_msgs/MarkerArray of posed parts for RViz: each part's model surface points and
a text label at its origin, built through a :class:`~tlessbot_ros.conversions.messages.
MessageFactory` (rclpy or rosbags messages)."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tlessbot_ros.conversions.messages import MessageFactory, default_factory, make_header
from tlessbot_ros.core.common import transform_points

MARKER_POINTS = 300     # surface points per part, at most
# visualization_msgs/Marker constants (the same in every message implementation)
ADD, DELETEALL = 0, 3
POINTS, TEXT_VIEW_FACING = 8, 9
COLOUR_RGBA = (0.1, 0.8, 0.3, 1.0)


@dataclass(frozen=True)
class PartMarker:
    """One posed part to show.

    Attributes:
        label: text shown at the part's origin, e.g. 'obj_05 (0.93)'.
        T_frame_object: (4, 4) the part's pose in ``frame_id``.
        frame_id: the frame of the pose.
        model_points: (N, 3) model surface points, metres, object frame.
    """

    label: str
    T_frame_object: np.ndarray
    frame_id: str
    model_points: np.ndarray


def parts_to_marker_array(parts: Sequence[PartMarker], stamp_ns: int, *,
                          max_points: int = MARKER_POINTS,
                          factory: MessageFactory | None = None) -> Any:
    """A MarkerArray that first deletes every earlier marker, then per part k a POINTS marker
    (namespace 'surface', id 2k, at most ``max_points`` points) and a TEXT_VIEW_FACING label
    (namespace 'label', id 2k + 1)."""
    factory = factory or default_factory()
    markers = [_marker(factory, action=DELETEALL)]
    for k, part in enumerate(parts):
        header = make_header(part.frame_id, stamp_ns, factory)
        colour = factory.new('std_msgs/msg/ColorRGBA', **dict(zip('rgba', COLOUR_RGBA)))
        step = max(1, len(part.model_points) // max_points)
        surface = transform_points(part.T_frame_object, part.model_points[::step])
        points = [_point(factory, xyz) for xyz in surface]
        markers.append(_marker(factory, header=header, ns='surface', id=2 * k, type=POINTS,
                               action=ADD, points=points, color=colour,
                               scale=_vector(factory, 0.003, 0.003, 0.0)))
        markers.append(_marker(factory, header=header, ns='label', id=2 * k + 1,
                               type=TEXT_VIEW_FACING, action=ADD, color=colour,
                               text=part.label, scale=_vector(factory, 0.0, 0.0, 0.02),
                               pose=_pose(factory, part.T_frame_object[:3, 3])))
    return factory.new('visualization_msgs/msg/MarkerArray', markers=markers)


def _marker(factory: MessageFactory, **fields: Any) -> Any:
    fields.setdefault('pose', _pose(factory, (0.0, 0.0, 0.0)))
    return factory.new('visualization_msgs/msg/Marker', **fields)


def _point(factory: MessageFactory, xyz: Sequence[float] | np.ndarray) -> Any:
    x, y, z = (float(v) for v in xyz)
    return factory.new('geometry_msgs/msg/Point', x=x, y=y, z=z)


def _vector(factory: MessageFactory, x: float, y: float, z: float) -> Any:
    return factory.new('geometry_msgs/msg/Vector3', x=x, y=y, z=z)


def _pose(factory: MessageFactory, position: Sequence[float] | np.ndarray) -> Any:
    """A Pose at ``position`` with the identity orientation (w = 1: a rosbags zero-filled
    Quaternion would not be a rotation)."""
    return factory.new('geometry_msgs/msg/Pose', position=_point(factory, position),
                       orientation=factory.new('geometry_msgs/msg/Quaternion', x=0.0, y=0.0,
                                               z=0.0, w=1.0))
