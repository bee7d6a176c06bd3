"""pose_estimator: 6D pose of every classified part, published for the arm.

Subscribes (``input_qos``), for CAMERA in top, side:
    /CAMERA/aligned_depth_to_color/image_raw     sensor_msgs/Image (16UC1 mm or 32FC1 m)
    /CAMERA/aligned_depth_to_color/camera_info   sensor_msgs/CameraInfo
    /classifier/CAMERA/classes                   sensor_msgs/Image 16UC1 class-instance labels,
                                                 or 16UC2..4: class candidates, best first
Publishes (RELIABLE, depth 10):
    objects/obj_NN/pose     geometry_msgs/PoseStamped, one message per found instance of object
                            NN, stamped with the source images' stamp, in the optical frame of
                            the camera that saw it best (side, else top) or in ``world_frame``
                            when ``output_frame`` is 'world'
    objects/markers         visualization_msgs/MarkerArray: model surface points + text label,
                            built only while subscribed (RViz)
    objects/debug_image     sensor_msgs/Image rgb8: side depth in false colour, part outlines
                            and the posed models' points, built only while subscribed
    /diagnostics            latency per stage, fitness, frames dropped, failures
Parameters: ``templates_path`` (.npz from ``tlessbot templates``; default: the packaged one),
``output_frame`` ('camera' or 'world'), ``world_frame``, ``min_fitness``,
``verify_accept_fitness``, ``verify_rmse_weight`` and ``fallback_min_fitness`` (how candidates
are verified), ``lookalike_check`` and ``lookalike_tolerance_m`` (look-alike parts told apart by
their depth at the fitted pose), ``pose.*``
(PoseParams), ``workers.*`` (PoseWorkerParams: worker processes that fit parts while this node
fits others), ``rig.CAMERA.*`` (extrinsics; the table path needs them), ``sync.*``.
"""
from __future__ import annotations

import dataclasses
import time
from typing import Any

import cv2
import numpy as np

from tlessbot_ros.conversions import (
    array_to_image,
    camera_info_to_intrinsics,
    depth_image_to_metres,
    image_to_array,
    stamp_to_ns,
    transform_to_pose_stamped,
)
from tlessbot_ros.conversions.messages import RclpyFactory
from tlessbot_ros.core.common import decode_candidates, project_points, transform_points
from tlessbot_ros.core.pipeline import Detection, PerceptionPipeline, PipelineParams, ViewInput
from tlessbot_ros.core.pose import PoseParams, TemplateDatabase
from tlessbot_ros.data import DEFAULT_TEMPLATES
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.nodes.common import RESULT_QOS, declare_from_dataclass, message_class, run_node
from tlessbot_ros.nodes.stage import StageNode, declare_extrinsics, descriptor
from tlessbot_ros.parallel.pose_pool import PoseWorkerParams, PoseWorkerPool

CLASS_ENCODINGS = ('16UC1', 'mono16', '16UC2', '16UC3', '16UC4')
IMAGE = 'sensor_msgs/msg/Image'
MARKER_POINTS = 300


def pose_topic(obj_id: int) -> str:
    return f'objects/obj_{obj_id:02d}/pose'


class PoseEstimatorNode(StageNode):
    """Class-instance labels + aligned depth -> PoseStamped per part."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('pose_estimator', **kwargs)
        path = self.declare_parameter('templates_path', str(DEFAULT_TEMPLATES), descriptor(
            'Template database .npz written by tlessbot templates')).value
        self.output_frame = self.declare_parameter('output_frame', 'camera', descriptor(
            "'camera': poses in the optical frame of the camera used; 'world': in "
            'world_frame through the rig extrinsics')).value
        self.world_frame = self.declare_parameter('world_frame', 'world', descriptor(
            'Name of the table (world) frame')).value
        self.min_fitness = self.declare_parameter('min_fitness', 0.3, descriptor(
            'Poses whose fitness is below this are not published')).value
        if self.output_frame not in ('camera', 'world'):
            raise TlessbotError(f"output_frame must be 'camera' or 'world', got "
                             f'{self.output_frame!r}')
        defaults = PipelineParams()
        accept = self.declare_parameter(
            'verify_accept_fitness', defaults.verify_accept_fitness, descriptor(
                'With several class candidates, the first is kept without fitting the others '
                'when its pose fitness reaches this')).value
        rmse_weight = self.declare_parameter(
            'verify_rmse_weight', defaults.verify_rmse_weight, descriptor(
                'Candidates are ranked by fitness - weight * inlier RMSE (1/m)')).value
        fallback_floor = self.declare_parameter(
            'fallback_min_fitness', defaults.fallback_min_fitness, descriptor(
                'No RANSAC fallback for a region that no class candidate fits at all (best '
                'fitness below this): no known part on the table')).value
        lookalike_check = self.declare_parameter(
            'lookalike_check', defaults.lookalike_check, descriptor(
                'A part whose class has a look-alike in the templates (obj_21/22, obj_25/26) is '
                'compared with it at the fitted pose: the mesh that explains more of the ROI '
                'depth names it')).value
        lookalike_tolerance = self.declare_parameter(
            'lookalike_tolerance_m', defaults.lookalike_tolerance_m, descriptor(
                'A pixel votes for one look-alike when it explains the depth better by more '
                'than this (m)')).value
        pose_params = dataclasses.replace(PoseParams(), **declare_from_dataclass(
            self, PoseParams(), prefix='pose.'))
        worker_params = dataclasses.replace(PoseWorkerParams(), **declare_from_dataclass(
            self, PoseWorkerParams(), prefix='workers.'))
        self.extrinsics = declare_extrinsics(self)
        self.templates = TemplateDatabase.load(path)
        pipeline_params = dataclasses.replace(
            defaults, verify_accept_fitness=float(accept), verify_rmse_weight=float(rmse_weight),
            fallback_min_fitness=float(fallback_floor), lookalike_check=bool(lookalike_check),
            lookalike_tolerance_m=float(lookalike_tolerance))
        self.pipeline = PerceptionPipeline(templates=self.templates, pose=pose_params,
                                           params=pipeline_params)
        # Workers load their templates while this process builds its caches below.
        self.workers = PoseWorkerPool(path, pose=pose_params, pipeline=pipeline_params,
                                      params=worker_params) if worker_params.count else None
        self._worker_errors_seen = 0
        self._factory = RclpyFactory()
        pose_class = message_class('geometry_msgs/msg/PoseStamped')
        self._pose_publishers = {obj_id: self.create_publisher(pose_class, pose_topic(obj_id),
                                                               RESULT_QOS)
                                 for obj_id in sorted(self.templates.objects)}
        self._markers = self.create_publisher(
            message_class('visualization_msgs/msg/MarkerArray'), 'objects/markers', RESULT_QOS)
        self._overlay = self.create_publisher(message_class(IMAGE), 'objects/debug_image',
                                              RESULT_QOS)
        started = time.perf_counter()
        self.pipeline.warm_up()
        if self.workers is not None and not self.workers.wait_ready():
            self.get_logger().warning(
                f'pose workers not ready ({"; ".join(self.workers.errors) or "still starting"}): '
                'parts are fitted here until they are')
        # Subscribed only now that the caches and workers are ready: a replay that waits for
        # subscribers then starts when this node can take frames.
        self.setup_inputs({
            'depth': (IMAGE, '/{camera}/aligned_depth_to_color/image_raw'),
            'info': ('sensor_msgs/msg/CameraInfo', '/{camera}/aligned_depth_to_color/camera_info'),
            'classes': (IMAGE, '/classifier/{camera}/classes'),
        })
        self.get_logger().info(f'templates for {len(self.templates.objects)} objects from {path}'
                               f' (caches built in {time.perf_counter() - started:.1f} s; '
                               f'{worker_params.count} worker processes)')

    def process(self, views: dict[str, dict[str, Any]]) -> None:
        inputs, labels, classes = {}, {}, {}
        for camera, msgs in views.items():
            intrinsics = camera_info_to_intrinsics(msgs['info'])
            depth = depth_image_to_metres(msgs['depth'])
            if msgs['classes'].encoding not in CLASS_ENCODINGS:
                raise ValueError(f'classes must be one of {CLASS_ENCODINGS}, got '
                                 f'{msgs["classes"].encoding!r}')
            class_image = image_to_array(msgs['classes'])
            if depth.shape != (intrinsics.height, intrinsics.width) or \
                    class_image.shape[:2] != depth.shape:
                raise ValueError(f'{camera}: depth {depth.shape}, classes {class_image.shape} '
                                 f'and CameraInfo {intrinsics.height}x{intrinsics.width} differ')
            inputs[camera] = ViewInput(rgb=None, depth_m=depth, intrinsics=intrinsics,
                                       T_world_camera=self.extrinsics[camera])
            labels[camera], view_classes = decode_candidates(class_image)
            classes.update(view_classes)
        stamp_ns = stamp_to_ns(views['side']['depth'].header.stamp)
        published = []

        def publish_pose(detection: Detection) -> None:
            # Each part goes out as soon as it is fitted: the arm can start on the first part
            # while the others are still being estimated.
            if detection.pose is not None and detection.pose.fitness >= self.min_fitness:
                self._pose_publishers[detection.obj_id].publish(self._pose_message(
                    detection, views[detection.view]['depth'].header.frame_id, stamp_ns))
                published.append(detection)

        self.pipeline.estimate_poses(inputs, labels, classes, on_detection=publish_pose,
                                     fitter=self.workers)
        self._log_worker_errors()
        if self._markers.get_subscription_count() > 0:
            self._markers.publish(self._marker_array(published, views, stamp_ns))
        if self._overlay.get_subscription_count() > 0:
            self._overlay.publish(self._overlay_image(published, views, inputs, labels, stamp_ns))
        fitness = [d.pose.fitness for d in published]
        stats = {'pose_objects': len(published),
                 'fitness_mean': float(np.mean(fitness)) if fitness else 0.0}
        if self.workers is not None:
            stats.update(workers_ready=self.workers.ready_count,
                         workers_replaced=self.workers.replaced,
                         worker_fits=self.workers.worker_fits)
        self.record_stats(stats)

    def _log_worker_errors(self) -> None:
        if self.workers is not None and self.workers.failures != self._worker_errors_seen:
            self._worker_errors_seen = self.workers.failures
            self.get_logger().error(f'{self.workers.errors[-1]} (its parts are fitted here; a '
                                    'new worker is starting)', throttle_duration_sec=5.0)

    def destroy_node(self) -> None:
        super().destroy_node()  # stops the frame worker thread first
        if self.workers is not None:
            self.workers.close()

    def _pose_in_output_frame(self, detection: Detection, camera_frame: str
                              ) -> tuple[np.ndarray, str]:
        T = detection.pose.T_camera_object
        if self.output_frame == 'world':
            return self.extrinsics[detection.view] @ T, self.world_frame
        return T, camera_frame

    def _pose_message(self, detection: Detection, camera_frame: str, stamp_ns: int) -> Any:
        T, frame = self._pose_in_output_frame(detection, camera_frame)
        return transform_to_pose_stamped(T, frame_id=frame, stamp_ns=stamp_ns,
                                         factory=self._factory)

    def _marker_array(self, detections: list[Detection], views: dict, stamp_ns: int) -> Any:
        from visualization_msgs.msg import Marker, MarkerArray

        factory = self._factory
        markers = [Marker(action=Marker.DELETEALL)]
        for k, detection in enumerate(detections):
            T, frame = self._pose_in_output_frame(
                detection, views[detection.view]['depth'].header.frame_id)
            header = factory.new('std_msgs/msg/Header', frame_id=frame,
                                 stamp=factory.new('builtin_interfaces/msg/Time',
                                                   sec=stamp_ns // 10**9,
                                                   nanosec=stamp_ns % 10**9))
            model = self.templates[detection.obj_id].model_points
            step = max(1, len(model) // MARKER_POINTS)
            surface = transform_points(T, model[::step])
            points = [factory.new('geometry_msgs/msg/Point', x=float(x), y=float(y), z=float(z))
                      for x, y, z in surface]
            colour = factory.new('std_msgs/msg/ColorRGBA', r=0.1, g=0.8, b=0.3, a=1.0)
            markers.append(Marker(header=header, ns='surface', id=2 * k, type=Marker.POINTS,
                                  action=Marker.ADD, points=points, color=colour))
            markers[-1].scale.x = markers[-1].scale.y = 0.003
            text = Marker(header=header, ns='label', id=2 * k + 1,
                          type=Marker.TEXT_VIEW_FACING, action=Marker.ADD, color=colour,
                          text=f'obj_{detection.obj_id:02d} ({detection.pose.fitness:.2f})')
            text.pose.position.x, text.pose.position.y, text.pose.position.z = \
                (float(v) for v in T[:3, 3])
            text.scale.z = 0.02
            markers.append(text)
        return MarkerArray(markers=markers)

    def _overlay_image(self, detections: list[Detection], views: dict,
                       inputs: dict[str, ViewInput], labels: dict[str, np.ndarray],
                       stamp_ns: int) -> Any:
        depth_msg = views['side']['depth']
        depth = np.nan_to_num(inputs['side'].depth_m, nan=0.0)
        valid = depth > 0
        span = np.percentile(depth[valid], [2, 98]) if valid.any() else np.array([0.0, 1.0])
        scaled = np.clip((depth - span[0]) / max(span[1] - span[0], 1e-6), 0, 1)
        canvas = cv2.applyColorMap((255 * (1 - scaled)).astype(np.uint8), cv2.COLORMAP_JET)
        canvas = np.ascontiguousarray(canvas[:, :, ::-1])
        canvas[~valid] = 0
        side_labels = labels['side'].astype(np.uint8 if labels['side'].max() < 256 else np.uint16)
        edges = cv2.morphologyEx((side_labels > 0).astype(np.uint8), cv2.MORPH_GRADIENT,
                                 np.ones((3, 3), np.uint8)) > 0
        canvas[edges] = (255, 255, 0)
        K = inputs['side'].intrinsics.K
        for detection in detections:
            if detection.view != 'side':
                continue
            model = self.templates[detection.obj_id].model_points[::5]
            uv = project_points(transform_points(detection.pose.T_camera_object, model), K)
            uv = np.round(uv[np.isfinite(uv).all(axis=1)]).astype(int)
            inside = (uv[:, 0] >= 0) & (uv[:, 0] < canvas.shape[1]) & (uv[:, 1] >= 0) & \
                (uv[:, 1] < canvas.shape[0])
            canvas[uv[inside, 1], uv[inside, 0]] = (0, 255, 0)
            x, y, _, _ = detection.box
            cv2.putText(canvas, f'obj_{detection.obj_id:02d}', (x, max(12, y - 4)),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 60, 60), 1, cv2.LINE_AA)
        return array_to_image(canvas, 'rgb8', frame_id=depth_msg.header.frame_id,
                              stamp_ns=stamp_ns, factory=self._factory)


def main(args: list[str] | None = None) -> None:
    run_node(PoseEstimatorNode, args)


if __name__ == '__main__':
    main()
