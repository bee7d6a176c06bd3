"""objects: the arm's side of the graph: instance names, TF, one message per frame, requests.

Subscribes:
    /pose_estimator/detections   vision_msgs/Detection3DArray, every part of a frame (unnamed)
    /localiser/rig               geometry_msgs/PoseArray, the observed rig (``rig_source``
                                 'localiser')
Publishes:
    /objects/detections  vision_msgs/Detection3DArray (RELIABLE, depth 10): every part of the
                         frame, ``id`` = instance name, in the pose stage's frames, an empty
                         array when there is none, stamped with the source images' stamp
    /tf                  tf2_msgs/TFMessage: a frame per part instance (``obj_05_1``), child
                         of the frame its pose is in, stamped with the source images' stamp
    /tf_static           tf2_msgs/TFMessage (TRANSIENT_LOCAL): ``world_frame`` to each
                         camera's ``<camera>_color_optical_frame``, from the rig in use; sent
                         again when it changes (a ``rig.*`` change, the observed rig)
    /diagnostics         frames, live instances, requests answered and timed out
Serves:
    /objects/get_objects  tlessbot_interfaces/GetObjects: the parts of the next frame the graph
                          completes after the request (optionally the agreement of N frames)
                          in the requested frame, or success false and why
Parameters: ``parts_path`` (as the stages: the part names and their symmetries),
``world_frame``, ``track.*`` (TrackParams: gates, time to live, time jump; live),
``request_timeout_s`` (live), ``rig.*`` and ``rig_source`` as the stages.
Frames: matching runs in ``world_frame`` through the rig; names reset on a time jump.
"""
from __future__ import annotations

import json
import threading
import time
from functools import partial
from typing import Any

import numpy as np
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from tlessbot_ros.conversions.camera import optical_frame
from tlessbot_ros.conversions.detections import (
    DETECTION_ARRAY,
    TF_MESSAGE,
    PartPose,
    detection_array_to_parts,
    part_to_detected_part,
    parts_to_detection_array,
    transforms_to_tf_message,
)
from tlessbot_ros.conversions.messages import RclpyFactory
from tlessbot_ros.conversions.pose import pose_array_to_camera_poses
from tlessbot_ros.conversions.topics import (
    DETECTIONS,
    GET_OBJECTS,
    OBSERVED_RIG,
    RAW_DETECTIONS,
    TF,
    TF_STATIC,
)
from tlessbot_ros.core.common import (
    CAMERA_NAMES,
    invert_transform,
    part_name,
    symmetries_from_models_info,
)
from tlessbot_ros.core.track import InstanceTracker, Observation, RequestBook, TrackParams
from tlessbot_ros.data import DEFAULT_MODELS_INFO
from tlessbot_ros.io.parts import PartsFolder
from tlessbot_ros.nodes.common import RESULT_QOS, message_class, run_node
from tlessbot_ros.nodes.diagnostics import OK, diagnostic_array
from tlessbot_ros.nodes.parameters import AT_ONCE, LiveParameters
from tlessbot_ros.nodes.parts import declare_parts
from tlessbot_ros.nodes.stage_config import RIG_QOS, declare_cameras, declare_extrinsics

TF_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                    depth=100)
TF_STATIC_QOS = QoSProfile(reliability=ReliabilityPolicy.RELIABLE,
                           durability=DurabilityPolicy.TRANSIENT_LOCAL,
                           history=HistoryPolicy.KEEP_LAST, depth=1)


class ObjectsNode(Node):
    """Unnamed parts per frame -> named parts, TF, Detection3DArray, GetObjects."""

    executor_kind = 'multi_threaded'   # requests wait in their own threads

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('objects', **kwargs)
        self.parameters = LiveParameters(self)
        self.cameras = declare_cameras(self.parameters)
        self.extrinsics = declare_extrinsics(self.parameters, self.cameras,
                                             self._apply_extrinsics)
        self.observed_rig: dict[str, np.ndarray] | None = None
        self.world_frame = self.parameters.read_only('world_frame', 'world',
                                                     'name of the table (world) frame')
        self.request_timeout_s = self.parameters.group(
            {'request_timeout_s': (5.0, 'default wait of a GetObjects request, s (> 0)')},
            build=_positive('request_timeout_s'),
            apply=partial(setattr, self, 'request_timeout_s'), when=AT_ONCE)
        self.tracker = InstanceTracker(symmetries=_part_symmetries(declare_parts(self)))
        self.tracker.params = self.parameters.dataclass(
            TrackParams(), prefix='track.', when=AT_ONCE,
            apply=partial(setattr, self.tracker, 'params'))
        self.requests = RequestBook()
        self.answered = self.timed_out = 0
        self._serving = 0   # requests in their service threads
        self._lock = threading.Lock()   # the tracker: frames and parameter changes
        self._factory = RclpyFactory()
        self._tf = self.create_publisher(message_class(TF_MESSAGE), TF, TF_QOS)
        self._tf_static = self.create_publisher(message_class(TF_MESSAGE), TF_STATIC,
                                                TF_STATIC_QOS)
        self._detections = self.create_publisher(message_class(DETECTION_ARRAY), DETECTIONS,
                                                 RESULT_QOS)
        self.create_subscription(message_class(DETECTION_ARRAY), RAW_DETECTIONS,
                                 self._on_frame, RESULT_QOS)
        source = self.parameters.read_only('rig_source', 'localiser', (
            "camera poses: 'localiser' (the observed rig once the localiser trusts it, "
            "rig.CAMERA.* until then) or 'config'"))
        if source == 'localiser':
            self.create_subscription(message_class('geometry_msgs/msg/PoseArray'),
                                     OBSERVED_RIG, self._on_observed_rig, RIG_QOS)
        from tlessbot_interfaces.srv import GetObjects
        self.create_service(GetObjects, GET_OBJECTS, self._on_request,
                            callback_group=ReentrantCallbackGroup())
        self._diagnostics = self.create_publisher(
            message_class('diagnostic_msgs/msg/DiagnosticArray'), '/diagnostics', RESULT_QOS)
        self.create_timer(1.0, self._publish_diagnostics)
        self._send_static()

    # ---------------------------------------------------------------------------- the rig
    def camera_pose(self, camera: str) -> np.ndarray:
        observed = self.observed_rig
        return observed[camera] if observed is not None else self.extrinsics[camera]

    def _apply_extrinsics(self, camera: str, T_world_camera: np.ndarray) -> None:
        self.extrinsics = {**self.extrinsics, camera: T_world_camera}
        self._send_static()

    def _on_observed_rig(self, msg: Any) -> None:
        try:
            self.observed_rig = pose_array_to_camera_poses(msg, names=CAMERA_NAMES)
        except ValueError as error:
            self.get_logger().warning(f'{OBSERVED_RIG}: {error}', throttle_duration_sec=5.0)
            return
        self._send_static()

    def _send_static(self) -> None:
        """world -> every camera's optical frame, all in one message (tf_static keeps one)."""
        stamp_ns = self.get_clock().now().nanoseconds
        self._tf_static.publish(transforms_to_tf_message(
            [(self.world_frame, optical_frame(c), self.camera_pose(c)) for c in self.cameras],
            stamp_ns=stamp_ns, factory=self._factory))

    def T_world(self, frame_id: str) -> np.ndarray:
        """``T_world_frame`` of the world frame or a camera's optical frame.

        Raises:
            ValueError: another frame.
        """
        if frame_id in ('', self.world_frame):
            return np.eye(4)
        for camera in self.cameras:
            if frame_id == optical_frame(camera):
                return self.camera_pose(camera)
        raise ValueError(f'unknown frame {frame_id!r}: use {self.world_frame!r} or one of '
                         f'{[optical_frame(c) for c in self.cameras]}')

    # ---------------------------------------------------------------------------- frames
    def _on_frame(self, msg: Any) -> None:
        """Name the frame's parts, publish them and TF, answer the waiting requests."""
        self.parameters.apply_pending()   # rig.* changes (the frame-time group)
        try:
            parts, stamp_ns = detection_array_to_parts(msg)
            world = [self.T_world(p.frame_id) @ p.T for p in parts]
        except ValueError as error:
            self.get_logger().warning(f'{RAW_DETECTIONS}: {error}', throttle_duration_sec=5.0)
            return
        with self._lock:
            tracked = self.tracker.update(stamp_ns, [Observation(p.part, T, p.score)
                                                     for p, T in zip(parts, world)])
        named, in_world = [], []
        for t in tracked:
            part = parts[t.index]
            T_frame = invert_transform(self.T_world(part.frame_id)) @ t.T_world_part
            named.append(PartPose(part.part, T_frame, part.frame_id, part.score, part.box_size_m,
                                  part.box_centre_m, t.instance))
            in_world.append(PartPose(part.part, t.T_world_part, self.world_frame, part.score,
                                     part.box_size_m, part.box_centre_m, t.instance))
        self._detections.publish(parts_to_detection_array(
            named, frame_id=msg.header.frame_id, stamp_ns=stamp_ns, factory=self._factory))
        if named:
            self._tf.publish(transforms_to_tf_message(
                [(p.frame_id, p.instance, p.T) for p in named], stamp_ns=stamp_ns,
                factory=self._factory))
        self.answered += self.requests.on_frame(stamp_ns, in_world)

    # ---------------------------------------------------------------------------- requests
    def _on_request(self, request: Any, response: Any) -> Any:
        with self._lock:
            self._serving += 1
        try:
            return self._answer(request, response)
        finally:
            with self._lock:
                self._serving -= 1

    def _answer(self, request: Any, response: Any) -> Any:
        """Wait (in this service thread) for the next frame, then answer in the asked frame."""
        try:
            T_frame_world = invert_transform(self.T_world(request.frame_id))
        except ValueError as error:
            return _refuse(response, str(error))
        timeout_s = request.timeout_s if request.timeout_s > 0 else self.request_timeout_s
        try:
            pending = self.requests.open(parts=list(request.parts), frames=request.frames)
        except ValueError as error:
            return _refuse(response, str(error))
        if not pending.wait(timeout_s):
            self.requests.close(pending)
            self.timed_out += 1
            return _refuse(response, self.requests.timeout_reason(timeout_s))
        if pending.cancelled:
            return _refuse(response, 'the objects node is stopping')
        frame = request.frame_id or self.world_frame
        response.success = True
        response.stamp.sec, response.stamp.nanosec = divmod(pending.stamp_ns, 1_000_000_000)
        response.parts = [part_to_detected_part(
            PartPose(p.part, T_frame_world @ p.T, frame, p.score, p.box_size_m,
                     p.box_centre_m, p.instance), stamp_ns=pending.stamp_ns,
            factory=self._factory) for p in sorted(pending.answer, key=lambda p: p.instance)]
        return response

    def _publish_diagnostics(self) -> None:
        values = {'frames': self.requests.frames, 'instances': len(self.tracker.instances),
                  'name_resets': self.tracker.resets, 'requests_waiting': self.requests.pending(),
                  'requests_answered': self.answered, 'requests_timed_out': self.timed_out}
        self._diagnostics.publish(diagnostic_array(self.get_clock().now().to_msg(),
                                                   self.get_name(), OK, 'running', values))


    def destroy_node(self) -> None:
        """Answer the waiting requests first, so that no reply goes out on a destroyed
        service."""
        self.requests.cancel_all()
        deadline = time.monotonic() + 2.0
        while self._serving and time.monotonic() < deadline:
            time.sleep(0.01)
        time.sleep(0.05)   # the executor sends the replies just returned
        super().destroy_node()


def _refuse(response: Any, message: str) -> Any:
    response.success, response.message = False, message
    return response


def _positive(name: str):
    def build(values: dict[str, Any]) -> float:
        value = float(values[name])
        if not value > 0:
            raise ValueError(f'{name} must be > 0, got {value}')
        return value
    return build


def _part_symmetries(folder: PartsFolder | None) -> dict[str, np.ndarray]:
    """{part name: (K, 4, 4) symmetry transforms} of the parts folder's models_info.json, or
    the packaged one's."""
    path = folder.models / 'models_info.json' if folder else DEFAULT_MODELS_INFO
    names = folder.names if folder else None
    if not path.is_file():
        return {}
    info = json.loads(path.read_text(encoding='utf-8'))
    out = {}
    for key, entry in info.items():
        symmetries = symmetries_from_models_info(entry)
        if not symmetries.is_trivial:
            out[part_name(int(key), names)] = symmetries.transforms(step_rad=np.radians(2.0))
    return out


def main(args: list[str] | None = None) -> None:
    run_node(ObjectsNode, args)


if __name__ == '__main__':
    main()
