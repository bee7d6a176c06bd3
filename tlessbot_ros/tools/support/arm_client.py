"""An arm-like client of the objects node: GetObjects requests, and each part's pose in the
world composed from /tf_static (world -> camera) and /tf (frame -> part instance).

Used by ``tlessbot objects`` and the tests; a pick-and-place cell does the same with tf2.
"""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from tlessbot_ros.conversions.detections import tf_message_to_transforms
from tlessbot_ros.conversions.pose import pose_stamped_to_transform
from tlessbot_ros.conversions.topics import GET_OBJECTS, TF, TF_STATIC


@dataclass
class PartAnswer:
    """One part of an answer: names, score, the pose in the requested frame, and the pose in
    the world composed from TF (None when TF had no chain for it)."""

    part: str
    instance: str
    score: float
    frame_id: str
    T_frame_part: np.ndarray
    box_size_m: tuple[float, float, float]
    T_world_part_tf: np.ndarray | None


@dataclass
class Answer:
    success: bool
    message: str
    stamp_ns: int
    parts: list[PartAnswer]
    latency_s: float


class ArmClient:
    """Owns an rclpy node (spun in a background thread) in an initialised context."""

    def __init__(self, node: Any, *, world_frame: str = 'world') -> None:
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from tf2_msgs.msg import TFMessage
        from tlessbot_interfaces.srv import GetObjects

        self.node = node
        self.world_frame = world_frame
        self._lock = threading.Lock()
        self.static: dict[str, tuple[str, np.ndarray]] = {}    # child -> (parent, T)
        self.dynamic: dict[tuple[str, int], tuple[str, np.ndarray]] = {}  # (child, stamp)
        static_qos = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                                durability=DurabilityPolicy.TRANSIENT_LOCAL,
                                history=HistoryPolicy.KEEP_LAST, depth=1)
        node.create_subscription(TFMessage, TF_STATIC, self._on_static, static_qos)
        node.create_subscription(TFMessage, TF, self._on_tf, QoSProfile(depth=100))
        self._client = node.create_client(GetObjects, GET_OBJECTS)
        self._request_class = GetObjects.Request

    def _on_static(self, msg: Any) -> None:
        with self._lock:
            for parent, child, T, _ in tf_message_to_transforms(msg):
                self.static[child] = (parent, T)

    def _on_tf(self, msg: Any) -> None:
        with self._lock:
            for parent, child, T, stamp_ns in tf_message_to_transforms(msg):
                self.dynamic[child, stamp_ns] = (parent, T)
            if len(self.dynamic) > 5000:   # bounded: forget the oldest stamps
                for key in sorted(self.dynamic, key=lambda k: k[1])[:1000]:
                    del self.dynamic[key]

    def wait_for_service(self, timeout_s: float) -> bool:
        return self._client.wait_for_service(timeout_sec=timeout_s)

    def world_pose(self, child: str, stamp_ns: int) -> np.ndarray | None:
        """``T_world_child`` at ``stamp_ns`` composed over /tf (at that stamp) and /tf_static."""
        T, frame = np.eye(4), child
        with self._lock:
            for _ in range(8):
                if frame == self.world_frame:
                    return T
                if (frame, stamp_ns) in self.dynamic:
                    parent, T_parent = self.dynamic[frame, stamp_ns]
                elif frame in self.static:
                    parent, T_parent = self.static[frame]
                else:
                    return None
                T, frame = T_parent @ T, parent
        return None

    def request(self, *, parts: list[str] | None = None, frame_id: str = '', frames: int = 1,
                timeout_s: float = 5.0, tf_wait_s: float = 3.0) -> Answer:
        """Call GetObjects and wait for the answer (and up to ``tf_wait_s`` for its TF)."""
        req = self._request_class(parts=list(parts or []), frame_id=frame_id, frames=frames,
                                  timeout_s=float(timeout_s))
        start = time.monotonic()
        future = self._client.call_async(req)
        done = threading.Event()
        future.add_done_callback(lambda _: done.set())
        if not done.wait(timeout_s + 5.0):
            return Answer(False, 'no answer from the objects node', 0, [],
                          time.monotonic() - start)
        latency = time.monotonic() - start
        res = future.result()
        stamp_ns = res.stamp.sec * 1_000_000_000 + res.stamp.nanosec
        answers = []
        for p in res.parts:
            T, frame, _ = pose_stamped_to_transform(p.pose)
            answers.append(PartAnswer(p.part, p.instance, p.score, frame, T,
                                      (p.box_size.x, p.box_size.y, p.box_size.z), None))
        deadline = time.monotonic() + tf_wait_s
        while answers and time.monotonic() < deadline:
            for a in answers:
                a.T_world_part_tf = self.world_pose(a.instance, stamp_ns)
            if all(a.T_world_part_tf is not None for a in answers):
                break
            time.sleep(0.01)
        return Answer(bool(res.success), str(res.message), stamp_ns, answers, latency)
