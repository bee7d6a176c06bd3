"""Two-view input synchronisation for the perception nodes.

Each camera's topics (e.g. colour, aligned depth, camera_info) are paired by stamp through a
bounded :class:`~tlessbot_ros.core.sync.StampSynchroniser`; complete per-camera sets are then
paired across cameras under ``max_age_s``. The callback gets
``{camera: {topic_key: message}}``. Everything is bounded: old frames are dropped and counted.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from rclpy.node import Node

from tlessbot_ros.conversions.messages import stamp_to_ns
from tlessbot_ros.core.sync import StampSynchroniser, SyncParams
from tlessbot_ros.nodes.common import SENSOR_QOS

Views = dict[str, dict[str, Any]]


class TwoViewInputs:
    """Subscribes ``/<camera>/<topic>`` for every camera and topic, emits synchronised views.

    Args:
        node: the owning node (subscriptions are created on it).
        topics: topic key -> (message class, topic template with ``{camera}``), e.g.
            ``{'color': (Image, '/{camera}/color/image_raw')}``.
        cameras: camera names; all must contribute to a view set.
        sync: thresholds; ``slop_s`` within a camera, ``max_age_s`` across cameras.
        callback: called with the views of one two-view frame.
        qos: subscription QoS (sensor data by default).
    """

    def __init__(self, node: Node, topics: dict[str, tuple[type, str]],
                 cameras: Sequence[str], sync: SyncParams,
                 callback: Callable[[Views], None], *, qos: Any = SENSOR_QOS) -> None:
        self._callback = callback
        self._per_camera = {
            camera: StampSynchroniser(list(topics), slop_ns=int(sync.slop_s * 1e9),
                                      queue_size=sync.queue_size) for camera in cameras}
        self._across = StampSynchroniser(list(cameras), slop_ns=int(sync.max_age_s * 1e9),
                                         queue_size=2)
        self.zero_stamps = 0
        for camera in cameras:
            for key, (msg_class, template) in topics.items():
                node.create_subscription(msg_class, template.format(camera=camera),
                                         self._handler(camera, key), qos)

    def _handler(self, camera: str, key: str) -> Callable[[Any], None]:
        def on_message(msg: Any) -> None:
            stamp = stamp_to_ns(msg.header.stamp)
            if stamp == 0:
                self.zero_stamps += 1  # cannot be synchronised; counted in diagnostics
                return
            complete = self._per_camera[camera].add(key, stamp, msg)
            if complete is None:
                return
            views = self._across.add(camera, stamp, complete)
            if views is not None:
                self._callback(views)
        return on_message

    @property
    def dropped(self) -> int:
        """Messages and camera sets discarded because their partners never came in time."""
        return self._across.dropped + sum(s.dropped for s in self._per_camera.values())
