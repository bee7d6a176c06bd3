"""Ground truth carried by simulated bags (see :mod:`tlessbot_ros.sim.bag` for the topics)."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tlessbot_ros.conversions.pose import pose_stamped_to_transform
from tlessbot_ros.errors import BagError
from tlessbot_ros.io.bags import bag_topics, deserialize, read_bag

INFO_TOPIC = '/ground_truth/info'
POSE_PREFIX = '/ground_truth/obj_'


@dataclass
class GroundTruthInstance:
    """One part of one frame.

    Attributes:
        obj_id: T-LESS id.
        instance: index of the part in the frame.
        T_camera_object: {optical frame id: (4, 4) pose in metres}.
        visib_fract: {camera name: visible fraction in that view}.
        bbox_visib: {camera name: (x, y, w, h) visible box}.
    """

    obj_id: int
    instance: int
    T_camera_object: dict[str, np.ndarray] = field(default_factory=dict)
    visib_fract: dict[str, float] = field(default_factory=dict)
    bbox_visib: dict[str, tuple[int, ...]] = field(default_factory=dict)

    @property
    def max_visib_fract(self) -> float:
        return max(self.visib_fract.values(), default=0.0)


def read_ground_truth(path: str | Path) -> dict[int, list[GroundTruthInstance]]:
    """{frame stamp (ns): instances} of a bag written by ``tlessbot simulate --bag``.

    Poses of several instances of one object on one topic are assigned to instances in the
    order the info message lists them (the writer's order).
    """
    topics = bag_topics(path)
    if INFO_TOPIC not in topics:
        raise BagError(f'bag {path} has no {INFO_TOPIC}: it carries no ground truth')
    frames: dict[int, list[GroundTruthInstance]] = {}
    poses: dict[tuple[int, int, str], list[np.ndarray]] = {}
    wanted = [INFO_TOPIC, *[t for t in topics if t.startswith(POSE_PREFIX)]]
    for message in read_bag(path, wanted):
        msg = deserialize(message)
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if message.topic == INFO_TOPIC:
            frames[stamp] = [_instance(status) for status in msg.status]
        else:
            T, frame_id, _ = pose_stamped_to_transform(msg)
            obj_id = int(message.topic[len(POSE_PREFIX):])
            poses.setdefault((stamp, obj_id, frame_id), []).append(T)
    for stamp, instances in frames.items():
        seen: dict[tuple[int, str], int] = {}
        for instance in instances:
            for (s, obj_id, frame_id), transforms in poses.items():
                if s != stamp or obj_id != instance.obj_id:
                    continue
                k = seen.get((obj_id, frame_id), 0)
                if k < len(transforms):
                    instance.T_camera_object[frame_id] = transforms[k]
                    seen[(obj_id, frame_id)] = k + 1
    return frames


def _instance(status) -> GroundTruthInstance:
    values = {kv.key: kv.value for kv in status.values}
    instance = GroundTruthInstance(int(values['obj_id']), int(values['instance']))
    for key, value in values.items():
        if key.startswith('visib_fract_'):
            instance.visib_fract[key[len('visib_fract_'):]] = float(value)
        elif key.startswith('bbox_visib_'):
            instance.bbox_visib[key[len('bbox_visib_'):]] = tuple(int(v) for v in value.split())
    return instance
