"""The arm's messages: vision_msgs/Detection3DArray, tf2_msgs/TFMessage and the GetObjects
answer's DetectedPart, from (4, 4) transforms and back.

A :class:`PartPose` is one part of a frame: its part name, pose in ``frame_id``, score, the box
around its model (size and centre in the part's frame, metres) and, once named, its instance
name. In a Detection3D it travels as one ObjectHypothesisWithPose (class_id = part name, score,
pose), the box, and ``id`` = instance name ('' before naming).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tlessbot_ros.conversions.messages import (
    MessageFactory,
    default_factory,
    make_header,
    stamp_to_ns,
)
from tlessbot_ros.conversions.pose import pose_to_transform, transform_to_pose_stamped
from tlessbot_ros.core.common import make_transform

DETECTION_ARRAY = 'vision_msgs/msg/Detection3DArray'
TF_MESSAGE = 'tf2_msgs/msg/TFMessage'
DETECTED_PART = 'tlessbot_interfaces/msg/DetectedPart'


@dataclass
class PartPose:
    """One part of a frame (see the module docstring); ``T`` is (4, 4) ``T_frame_part``."""

    part: str
    T: np.ndarray
    frame_id: str
    score: float = 1.0
    box_size_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    box_centre_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    instance: str = ''


def _pose(T: np.ndarray, factory: MessageFactory) -> Any:
    return transform_to_pose_stamped(T, frame_id='', stamp_ns=0, factory=factory).pose


def _vector3(values: np.ndarray, factory: MessageFactory) -> Any:
    x, y, z = (float(v) for v in np.asarray(values, dtype=np.float64).reshape(3))
    return factory.new('geometry_msgs/msg/Vector3', x=x, y=y, z=z)


def parts_to_detection_array(parts: Sequence[PartPose], *, frame_id: str, stamp_ns: int,
                             factory: MessageFactory | None = None) -> Any:
    """Detection3DArray of a frame's parts (empty when there is none), every header stamped
    ``stamp_ns``; the array's header names ``frame_id``, each detection its part's frame."""
    factory = factory or default_factory()
    detections = []
    for part in parts:
        hypothesis = factory.new(
            'vision_msgs/msg/ObjectHypothesisWithPose',
            hypothesis=factory.new('vision_msgs/msg/ObjectHypothesis', class_id=part.part,
                                   score=float(part.score)),
            pose=factory.new('geometry_msgs/msg/PoseWithCovariance',
                             pose=_pose(part.T, factory)))
        centre = part.T @ make_transform(np.eye(3), np.asarray(part.box_centre_m, float))
        box = factory.new('vision_msgs/msg/BoundingBox3D', center=_pose(centre, factory),
                          size=_vector3(part.box_size_m, factory))
        detections.append(factory.new(
            'vision_msgs/msg/Detection3D', header=make_header(part.frame_id, stamp_ns, factory),
            results=[hypothesis], bbox=box, id=part.instance))
    return factory.new(DETECTION_ARRAY, header=make_header(frame_id, stamp_ns, factory),
                       detections=detections)


def detection_array_to_parts(msg: Any) -> tuple[list[PartPose], int]:
    """The parts of a Detection3DArray written by :func:`parts_to_detection_array` and its
    stamp in ns. A detection's best hypothesis names the part.

    Raises:
        ValueError: a detection without a hypothesis, or with an invalid pose.
    """
    parts = []
    for detection in msg.detections:
        if not detection.results:
            raise ValueError('a Detection3D has no hypothesis (results is empty)')
        best = max(detection.results, key=lambda r: r.hypothesis.score)
        pose, box = best.pose.pose, detection.bbox.center
        T = pose_to_transform(pose.position, pose.orientation, what='a Detection3D pose')
        box_T = pose_to_transform(box.position, box.orientation, what='a Detection3D box')
        size = detection.bbox.size
        parts.append(PartPose(
            part=str(best.hypothesis.class_id), T=T, frame_id=str(detection.header.frame_id),
            score=float(best.hypothesis.score),
            box_size_m=np.array([size.x, size.y, size.z], dtype=np.float64),
            box_centre_m=(np.linalg.inv(T) @ box_T)[:3, 3], instance=str(detection.id)))
    return parts, stamp_to_ns(msg.header.stamp)


def transforms_to_tf_message(transforms: Sequence[tuple[str, str, np.ndarray]], *,
                             stamp_ns: int, factory: MessageFactory | None = None) -> Any:
    """TFMessage of ``(parent_frame, child_frame, T_parent_child)`` triples, all stamped
    ``stamp_ns``."""
    factory = factory or default_factory()
    messages = []
    for parent, child, T in transforms:
        pose = _pose(T, factory)
        translation = factory.new('geometry_msgs/msg/Vector3', x=pose.position.x,
                                  y=pose.position.y, z=pose.position.z)
        messages.append(factory.new(
            'geometry_msgs/msg/TransformStamped', header=make_header(parent, stamp_ns, factory),
            child_frame_id=child,
            transform=factory.new('geometry_msgs/msg/Transform', translation=translation,
                                  rotation=pose.orientation)))
    return factory.new(TF_MESSAGE, transforms=messages)


def tf_message_to_transforms(msg: Any) -> list[tuple[str, str, np.ndarray, int]]:
    """``(parent, child, T_parent_child, stamp_ns)`` of each transform of a TFMessage.

    Raises:
        ValueError: a transform with a zero quaternion or non-finite values.
    """
    out = []
    for item in msg.transforms:
        T = pose_to_transform(item.transform.translation, item.transform.rotation,
                              what=f'the transform to {item.child_frame_id}')
        out.append((str(item.header.frame_id), str(item.child_frame_id), T,
                    stamp_to_ns(item.header.stamp)))
    return out


def part_to_detected_part(part: PartPose, *, stamp_ns: int,
                          factory: MessageFactory | None = None) -> Any:
    """A GetObjects answer's DetectedPart (pose in ``part.frame_id``)."""
    factory = factory or default_factory()
    return factory.new(
        DETECTED_PART, part=part.part, instance=part.instance, score=float(part.score),
        pose=transform_to_pose_stamped(part.T, frame_id=part.frame_id, stamp_ns=stamp_ns,
                                       factory=factory),
        box_size=_vector3(part.box_size_m, factory))
