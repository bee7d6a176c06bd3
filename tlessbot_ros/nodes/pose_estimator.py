"""pose_estimator: 6D pose of every classified part, published for the arm.

Subscribes (``input_qos``), for CAMERA in top, side:
    /CAMERA/aligned_depth_to_color/image_raw     sensor_msgs/Image (16UC1 mm or 32FC1 m)
    /CAMERA/aligned_depth_to_color/camera_info   sensor_msgs/CameraInfo
    /classifier/CAMERA/classes                   sensor_msgs/Image 16UC1 class-instance labels,
                                                 or 16UC2..4: class candidates, best first
Publishes (RELIABLE, depth 10):
    objects/<name>/pose     geometry_msgs/PoseStamped, one message per found instance of a
                            part (its name: the parts folder's, T-LESS obj_NN), stamped
                            with the source images' stamp, in the optical frame of
                            the camera that saw it best (side, else top) or in ``world_frame``
                            when ``output_frame`` is 'world'
    pose_estimator/detections  vision_msgs/Detection3DArray: every part of the frame (an empty
                            array when none), unnamed, for the objects node (nodes/objects.py);
                            not published where vision_msgs is missing
    objects/markers         visualization_msgs/MarkerArray: model surface points + text label,
                            built only while subscribed (RViz)
    objects/debug_image     sensor_msgs/Image rgb8: side depth (the one camera's in a rig of
                            one camera) in false colour, part outlines
                            and the posed models' points, built only while subscribed
    /diagnostics            latency per stage, fitness, frames dropped, failures
Parameters: ``parts_path`` (a parts folder of ``tlessbot parts build``: its templates and part
names; default '': the packaged T-LESS parts), ``templates_path`` (.npz from ``tlessbot
templates``; default: the parts folder's, else the packaged one),
``output_frame`` ('camera' or 'world'), ``world_frame``, ``min_fitness``,
``verify_accept_fitness``, ``verify_rmse_weight``, ``verify_inlier_m``, ``verify_overrule_margin``,
``verify_points`` and ``fallback_min_fitness`` (how candidates
are verified), ``lookalike_check``, ``lookalike_tolerance_m``, ``lookalike_min_z`` and
``lookalike_all_views`` (look-alike parts told apart by their depth in both views at the fitted
pose, checked in this process; ``lookalike_refine``: on per-pixel depth, twins left open there
vote again, each from where its surface explains the most depth; ``lookalike_edge_min_z``: first
by the colour image's edges, ``lookalike_shut_holes``: a twin's hole the image shows shut too),
``flat.*`` (flat parts: the face that is up, told by the depth
of both views and, with ``colour_input``, the colour image), ``turns.*`` (parts that are not
flat: a near-symmetric turn of the fit that the colour image's edges support better, with
``colour_input``), ``resting.*`` (a fit on the table levelled onto the nearest stable pose of
its part when that fits as well; these and ``min_roi_points``,
``table_clearance_m``, ``steep_angle_deg``: FitParams),
``pose.*``
(PoseParams), ``workers.*`` (PoseWorkerParams: worker processes that fit parts while this node
fits others, on frames that find ``parallel.min_spare_cores`` free beside its work or idle:
SpareCpuParams),
``rig.cameras`` (the names of the top and side cameras, or of one camera), ``rig.CAMERA.*``
(extrinsics; the table path needs them), ``rig_source`` ('localiser': the camera poses the
localiser publishes on /localiser/rig once it refines the rig from the scene replace
``rig.CAMERA.*``, also for ``output_frame`` 'world'; 'config'), ``sync.*``. All are live
(``ros2 param set``, from the next frame; the worker processes fit their next part with new
``pose.*`` and FitParams; ``workers.count`` starts or stops workers) but ``templates_path``
and ``parts_path`` (their objects name the pose topics), ``rig.cameras``, ``rig_source``,
``input_qos``, ``input_depth``, ``sync.worker_thread``, ``sync.executor``, ``colour_input``
(with it also /CAMERA/color/image_raw: flat and near-symmetric parts checked on the colour
image too, FitParams ``flat.*`` and ``turns.*``; on by default with ``parts_path``): read-only.
"""
from __future__ import annotations

import time
from functools import partial
from typing import Any

import numpy as np

from tlessbot_ros.conversions import (
    array_to_image,
    camera_info_to_intrinsics,
    depth_image_to_metres,
    image_to_array,
    image_to_rgb,
    stamp_to_ns,
    transform_to_pose_stamped,
)
from tlessbot_ros.conversions.detections import DETECTION_ARRAY, PartPose, parts_to_detection_array
from tlessbot_ros.conversions.image_cdr import image_from_cdr, image_to_cdr
from tlessbot_ros.conversions.markers import PartMarker, parts_to_marker_array
from tlessbot_ros.conversions.messages import RclpyFactory
from tlessbot_ros.conversions.topics import (
    DEBUG_IMAGE,
    MARKERS,
    RAW_DETECTIONS,
    classes_topic,
    node_relative,
    pose_topic,
)
from tlessbot_ros.core.common import (
    OverlayPart,
    decode_candidates,
    depth_overlay,
    label_boxes,
    part_name,
)
from tlessbot_ros.core.pipeline import Detection, FitParams, PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import PoseParams, TemplateDatabase
from tlessbot_ros.data import DEFAULT_TEMPLATES
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.cache import warm_pose_stage
from tlessbot_ros.nodes.common import RESULT_QOS, message_class, run_node
from tlessbot_ros.nodes.parts import declare_parts
from tlessbot_ros.nodes.stage import (
    IMAGE,
    StageNode,
    camera_inputs,
    declare_spare_cpu,
    follow_observed_rig,
)
from tlessbot_ros.parallel.pose_pool import PoseWorkerParams, PoseWorkerPool

CLASS_ENCODINGS = ('16UC1', 'mono16', '16UC2', '16UC3', '16UC4')
OUTPUT_FRAMES = ('camera', 'world')


class PoseEstimatorNode(StageNode):
    """Class-instance labels + aligned depth -> PoseStamped per part."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('pose_estimator', after_localiser=True, **kwargs)
        parameters = self.parameters
        parts = declare_parts(self)   # PartsFolderError: one line, exit 1
        # A parts folder's flat and near-symmetric parts are told apart on the colour image
        # (flat.*, turns.*), as `tlessbot evaluate` scores them; the packaged T-LESS graph
        # keeps its two depth inputs.
        self.colour_input = parameters.read_only('colour_input', parts is not None, (
            'Also subscribe to the colour images: flat and near-symmetric parts are checked '
            'on them (flat.*, turns.*); default: on with parts_path, off without'))
        path = parameters.read_only(
            'templates_path', str(parts.templates if parts else DEFAULT_TEMPLATES), (
                "Template database .npz written by tlessbot templates (default: the parts "
                "folder's, else the packaged one); its objects are the pose topics"))
        self.output_frame = parameters.group(
            {'output_frame': ('camera', "'camera': poses in the optical frame of the camera "
                                        "used; 'world': in world_frame through the rig "
                                        'extrinsics')},
            build=_output_frame, apply=partial(setattr, self, 'output_frame'))
        self.world_frame = parameters.group(
            {'world_frame': ('world', 'Name of the table (world) frame')},
            build=_world_frame, apply=partial(setattr, self, 'world_frame'))
        self.min_fitness = parameters.group(
            {'min_fitness': (0.3, 'Poses whose fitness is below this are not published')},
            build=_min_fitness, apply=partial(setattr, self, 'min_fitness'))
        pose_params = parameters.dataclass(PoseParams(), prefix='pose.',
                                           apply=self._apply_pose_params)
        worker_params = parameters.dataclass(PoseWorkerParams(), prefix='workers.',
                                             apply=self._apply_worker_params)
        fit_params = parameters.dataclass(FitParams(), apply=self._apply_fit_params)
        self.templates = TemplateDatabase.load(path)
        self.part_names = parts.names if parts else {}   # none: obj_NN
        self.pipeline = PerceptionPipeline(templates=self.templates, pose=pose_params,
                                           fit_params=fit_params)
        # Workers load their templates while this process builds its caches below.
        self.workers = PoseWorkerPool(path, pose=pose_params, fit=fit_params,
                                      params=worker_params) if worker_params.count else None
        self.spare_cpu = declare_spare_cpu(self)
        self.spare_cpu.own_cpu_s = self._own_cpu_s
        self._worker_errors_seen = 0
        self._factory = RclpyFactory()
        self._templates_path = path
        self.rig_source = follow_observed_rig(self)
        self._create_publishers()
        inputs = camera_inputs(('color', 'depth', 'info') if self.colour_input else
                               ('depth', 'info'), self.input_source)
        self.start_when_ready(self._warm_up, {**inputs, 'classes': (IMAGE, classes_topic)})

    def _create_publishers(self) -> None:
        pose_class = message_class('geometry_msgs/msg/PoseStamped')
        self._pose_publishers = {
            obj_id: self.create_publisher(
                pose_class, node_relative(pose_topic(obj_id, self.part_names)), RESULT_QOS)
            for obj_id in sorted(self.templates.objects)}
        self._markers = self.create_publisher(
            message_class('visualization_msgs/msg/MarkerArray'), node_relative(MARKERS),
            RESULT_QOS)
        self._overlay = self.create_publisher(message_class(IMAGE), node_relative(DEBUG_IMAGE),
                                              RESULT_QOS)
        try:
            self._detections = self.create_publisher(message_class(DETECTION_ARRAY),
                                                     node_relative(RAW_DETECTIONS), RESULT_QOS)
        except ValueError as error:   # a ROS install without vision_msgs
            self._detections = None
            self.get_logger().warning(f'{error}: {RAW_DETECTIONS} is not published')

    def _warm_up(self) -> None:
        """Every cache the first frame would build (from the start-up cache when it has them,
        :func:`~tlessbot_ros.io.cache.warm_pose_stage`), the numba kernels, and the workers."""
        report = warm_pose_stage(self.pipeline, self._templates_path,
                                 colour=self.colour_input)
        # The label kernels of a frame's first steps, on a class image read as one arrives.
        label_boxes(decode_candidates(image_to_array(image_from_cdr(image_to_cdr(
            np.full((4, 4, 2), 1001, np.uint16), '16UC2'))))[0])
        depth_image_to_metres(image_from_cdr(image_to_cdr(np.ones((2, 4), np.uint16), '16UC1')))
        self.get_logger().info(
            f'templates for {len(self.templates.objects)} objects from {self._templates_path}: '
            f'caches {"read" if report.from_cache else "built"} in {report.seconds:.1f} s')
        if self.workers is not None and not self.workers.wait_ready():
            self.get_logger().warning(
                f'pose workers not ready ({"; ".join(self.workers.errors) or "still starting"}): '
                'parts are fitted here until they are')

    def process(self, views: dict[str, dict[str, Any]]) -> None:
        inputs, labels, classes = {}, {}, {}
        for camera, msgs in views.items():
            inputs[camera], labels[camera], view_classes = self._view_input(camera, msgs)
            classes.update(view_classes)
        stamp_ns = stamp_to_ns(views[self.main_camera]['depth'].header.stamp)
        published = []

        def publish_pose(detection: Detection) -> None:
            # Each part goes out as soon as it is fitted: the arm can start on the first part
            # while the others are still being estimated.
            if detection.pose is not None and detection.pose.fitness >= self.min_fitness:
                self._pose_publishers[detection.obj_id].publish(self._pose_message(
                    detection, views[detection.view]['depth'].header.frame_id, stamp_ns))
                published.append(detection)

        # the workers fit parts beside this thread only while a core was free beside this
        # stage's work, or idle, lately (parallel.min_spare_cores); otherwise every part is
        # fitted here
        with self.spare_cpu.work(self.workers is not None) as split:
            self.pipeline.estimate_poses(inputs, labels, classes, on_detection=publish_pose,
                                         fitter=self.workers if split else None)
        self._log_worker_errors()
        self._publish_detections(published, views, stamp_ns)
        self._publish_debug(published, views, inputs, labels, stamp_ns)
        self.record_stats(self._frame_stats(published))

    def _view_input(self, camera: str, msgs: dict[str, Any]
                    ) -> tuple[ViewInput, np.ndarray, dict[int, tuple[int, ...]]]:
        """One camera's ViewInput, instance labels and {instance: class candidates}."""
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
        rgb = image_to_rgb(msgs['color']) if 'color' in msgs else None
        if rgb is not None and rgb.shape[:2] != depth.shape:
            raise ValueError(f'{camera}: colour {rgb.shape[:2]} and depth {depth.shape} differ')
        view = ViewInput(rgb=rgb, depth_m=depth, intrinsics=intrinsics,
                         T_world_camera=self.camera_pose(camera))
        return (view, *decode_candidates(class_image))

    def _frame_stats(self, published: list[Detection]) -> dict[str, float]:
        fitness = [d.pose.fitness for d in published]
        stats = {'pose_objects': len(published),
                 'fitness_mean': float(np.mean(fitness)) if fitness else 0.0,
                 'flat_turned': sum(d.turned_over for d in published)}
        if self.workers is not None:
            stats.update(workers_ready=self.workers.ready_count,
                         workers_replaced=self.workers.replaced,
                         worker_fits=self.workers.worker_fits, **self.spare_cpu.stats())
        return stats

    def _apply_pose_params(self, params: PoseParams) -> None:
        self.pipeline = self.pipeline.replace(pose=params)
        self._update_workers()

    def _apply_fit_params(self, params: FitParams) -> None:
        self.pipeline = self.pipeline.replace(fit_params=params)
        self._update_workers()

    def _update_workers(self) -> None:
        """The workers fit their next parts with the pipeline's current settings."""
        if self.workers is not None:
            self.workers.update(pose=self.pipeline.pose_estimator.params,
                                fit=self.pipeline.fit_params)

    def _own_cpu_s(self) -> float:
        """CPU time of this stage so far, seconds: this process and its pose workers."""
        workers = self.workers
        return time.process_time() + (workers.cpu_seconds() if workers is not None else 0.0)

    def _apply_worker_params(self, params: PoseWorkerParams) -> None:
        """Start or stop worker processes (new ones fit parts once they are ready)."""
        if self.workers is None and params.count:
            self.workers = PoseWorkerPool(self._templates_path,
                                          pose=self.pipeline.pose_estimator.params,
                                          fit=self.pipeline.fit_params, params=params)
        elif self.workers is not None:
            self.workers.reconfigure(params)

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
            return self.camera_pose(detection.view) @ T, self.world_frame
        return T, camera_frame

    def _pose_message(self, detection: Detection, camera_frame: str, stamp_ns: int) -> Any:
        T, frame = self._pose_in_output_frame(detection, camera_frame)
        return transform_to_pose_stamped(T, frame_id=frame, stamp_ns=stamp_ns,
                                         factory=self._factory)

    def _publish_detections(self, detections: list[Detection], views: dict,
                            stamp_ns: int) -> None:
        """The frame's parts in one array, also when there is none."""
        if self._detections is None:
            return
        parts = []
        for d in detections:
            T, frame = self._pose_in_output_frame(d, views[d.view]['depth'].header.frame_id)
            points = self.templates[d.obj_id].model_points
            low, high = points.min(axis=0), points.max(axis=0)
            parts.append(PartPose(part_name(d.obj_id, self.part_names), T, frame,
                                  float(d.pose.fitness), high - low, (high + low) / 2))
        frame = self.world_frame if self.output_frame == 'world' else \
            views[self.main_camera]['depth'].header.frame_id
        self._detections.publish(parts_to_detection_array(parts, frame_id=frame,
                                                          stamp_ns=stamp_ns,
                                                          factory=self._factory))

    def _publish_debug(self, detections: list[Detection], views: dict,
                       inputs: dict[str, ViewInput], labels: dict[str, np.ndarray],
                       stamp_ns: int) -> None:
        """RViz markers and the side view's overlay, each built only while subscribed."""
        if self._markers.get_subscription_count() > 0:
            parts = []
            for d in detections:
                T, frame = self._pose_in_output_frame(d, views[d.view]['depth'].header.frame_id)
                label = f'{part_name(d.obj_id, self.part_names)} ({d.pose.fitness:.2f})'
                parts.append(PartMarker(label, T, frame, self.templates[d.obj_id].model_points))
            self._markers.publish(parts_to_marker_array(parts, stamp_ns, factory=self._factory))
        if self._overlay.get_subscription_count() > 0:
            main = self.main_camera
            canvas = depth_overlay(inputs[main].depth_m, labels[main], inputs[main].intrinsics.K, [
                OverlayPart(part_name(d.obj_id, self.part_names), d.box, d.pose.T_camera_object,
                            self.templates[d.obj_id].model_points)
                for d in detections if d.view == main])
            self._overlay.publish(array_to_image(
                canvas, 'rgb8', frame_id=views[main]['depth'].header.frame_id,
                stamp_ns=stamp_ns, factory=self._factory))


def _output_frame(values: dict[str, Any]) -> str:
    frame = values['output_frame']
    if frame not in OUTPUT_FRAMES:
        raise TlessbotError(f"output_frame must be 'camera' or 'world', got {frame!r}")
    return frame


def _world_frame(values: dict[str, Any]) -> str:
    frame = values['world_frame']
    if not frame:
        raise ValueError('world_frame must name a frame, got an empty string')
    return frame


def _min_fitness(values: dict[str, Any]) -> float:
    fitness = values['min_fitness']
    if not fitness >= 0.0:   # NaN too
        raise ValueError(f'min_fitness must be >= 0 (a fitness; above 1: no pose is '
                         f'published), got {fitness}')
    return fitness


def main(args: list[str] | None = None) -> None:
    run_node(PoseEstimatorNode, args)


if __name__ == '__main__':
    main()
