"""localiser: segments the top and side colour images and fuses them into instance labels.

Subscribes (sensor-data QoS), for CAMERA in top, side:
    /CAMERA/color/image_raw                      sensor_msgs/Image (rgb8, bgr8, ...)
    /CAMERA/aligned_depth_to_color/image_raw     sensor_msgs/Image (16UC1 mm or 32FC1 m)
    /CAMERA/aligned_depth_to_color/camera_info   sensor_msgs/CameraInfo
Publishes (RELIABLE, depth 10):
    localiser/CAMERA/labels   sensor_msgs/Image 16UC1: 0 = background, 1..N instances; the same
                              id marks the same part in both views (header = colour header)
    /diagnostics              frames, failures, dropped, latency, stage times; the rig
                              refinement's state (``rig_*``): WARN when the configured rig is
                              off from what the cameras see by more than
                              ``rig_refinement.warn_*``
    localiser/CAMERA/color/image_raw, localiser/CAMERA/aligned_depth_to_color/{image_raw,
    camera_info}              the camera messages of the frames it admits, relayed as received,
                              for the later stages (``input_source: localiser``)
Subscribes (RELIABLE), for backpressure:
    /classifier/frames, /pose_estimator/frames   std_msgs/Header: stamp = a frame's stamp,
                                                 frame_id = done | dropped | failed
Admission: the localiser is the graph's entrance; it holds the
:class:`~tlessbot_ros.nodes.admission.Entrance` (backpressure, ``admission.*``): a complete
frame is taken only while fewer than ``admission.max_in_flight`` frames it has taken are still
unfinished downstream, and the camera subscriptions are not read while it is full
(:mod:`~tlessbot_ros.nodes.admission` says how).
Parameters: ``parts_path`` (a parts folder of ``tlessbot parts build``, read-only: its parts'
sizes set each view's smallest blob and opening, core/localise/part_scale.py),
``admission.*`` (AdmissionParams), ``parallel_views`` (LocaliseParams: segment
both views at once, in two threads, while ``parallel.min_spare_cores`` are free beside its
work or idle lately: SpareCpuParams),
``segmentation.*`` (SegmentationParams), ``fusion.*``
(FusionParams: method calibrated | algorithm1 | side_only), ``sync.*`` (SyncParams),
``rig.cameras`` (the names of the top and side cameras, or of the one camera: its
segmentation alone then, no fusion or rig refinement), ``rig.CAMERA.*`` (extrinsics),
``rig_refinement.*`` (RigRefinementParams: mode none | report | use, thresholds; the rig
estimated from the table planes and the parts both cameras see,
:mod:`~tlessbot_ros.core.calibrate.refinement`, and used by the fusion once confident),
``background.CAMERA`` (path of an empty-table PNG for background subtraction; '' = none; a new
one that cannot be read is refused). All are live (``ros2 param set``, from the next frame)
but ``rig.cameras``, ``input_qos``, ``input_depth``, ``sync.worker_thread``, ``sync.executor``:
read-only.
Frames: outputs keep each source image's frame and stamp.
"""
from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import Any

import cv2
import numpy as np

from tlessbot_ros.conversions import (
    camera_info_to_intrinsics,
    depth_image_to_metres,
    image_to_rgb,
    stamp_to_ns,
)
from tlessbot_ros.conversions.image_cdr import image_to_cdr
from tlessbot_ros.conversions.messages import RclpyFactory, message_class
from tlessbot_ros.conversions.outcomes import read_frame_outcome
from tlessbot_ros.conversions.pose import camera_poses_to_pose_array
from tlessbot_ros.conversions.topics import (
    OBSERVED_RIG,
    labels_topic,
    node_relative,
    outcome_topic,
    relay_topic,
)
from tlessbot_ros.core.calibrate.refinement import (
    RigRefinementParams,
    RigRefiner,
    refined_pipeline,
)
from tlessbot_ros.core.common import CAMERA_NAMES, AdmissionParams, InFlightFrames, Rig
from tlessbot_ros.core.localise import (
    BackgroundModel,
    FusionParams,
    SegmentationParams,
    prepare_background,
)
from tlessbot_ros.core.pipeline import LocaliseParams, PerceptionPipeline, ViewInput
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.nodes.admission import Entrance
from tlessbot_ros.nodes.inputs import Views
from tlessbot_ros.nodes.parts import declare_parts
from tlessbot_ros.nodes.qos import RESULT_QOS
from tlessbot_ros.nodes.spin import run_node
from tlessbot_ros.nodes.stage import (
    CAMERA_INPUTS,
    IMAGE,
    RIG_QOS,
    StageNode,
    camera_inputs,
    declare_spare_cpu,
    rig_with_intrinsics,
)

# The stages after the localiser; the last one's 'done' ends a frame's trip through the graph.
DOWNSTREAM = ('classifier', 'pose_estimator')


class LocaliserNode(StageNode):
    """Segmentation + two-view fusion -> instance label images."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('localiser', pauses_inputs=True, **kwargs)
        parts = declare_parts(self)   # PartsFolderError: one line, exit 1
        # the parts' sizes set each view's smallest blob and opening (core/localise/part_scale)
        self.part_extents_m = None if parts is None else parts.extents_m
        self.segmentation = self.parameters.dataclass(
            SegmentationParams(), prefix='segmentation.', apply=self._apply_segmentation)
        self.fusion = self.parameters.dataclass(FusionParams(), prefix='fusion.',
                                                apply=partial(setattr, self, 'fusion'))
        self.localise_params = self.parameters.dataclass(
            LocaliseParams(), apply=partial(setattr, self, 'localise_params'))
        self.spare_cpu = declare_spare_cpu(self)
        self._views_in_parallel = self.localise_params.parallel_views   # this frame's choice
        self.rig_refinement = self.parameters.dataclass(
            RigRefinementParams(), prefix='rig_refinement.', apply=self._apply_rig_refinement)
        self.refiner: RigRefiner | None = None   # made on the first frame (its intrinsics)
        self._rig_status: tuple[str, dict[str, str]] = ('', {})
        self._rig_publisher = self.create_publisher(
            message_class('geometry_msgs/msg/PoseArray'), node_relative(OBSERVED_RIG), RIG_QOS)
        self._published_rig: Rig | None = None
        self._rig_factory = RclpyFactory()
        self._empty_tables: dict[str, np.ndarray] = {}   # camera: (H, W, 3) uint8 RGB
        self.backgrounds: dict[str, BackgroundModel] = {}
        for camera in self.cameras:
            name = f'background.{camera}'
            self._apply_background(camera, self.parameters.group(
                {name: ('', f'empty-table PNG of the {camera} camera for background '
                            "subtraction ('' = none)")},
                build=lambda values, name=name: read_empty_table(values[name]),
                apply=partial(self._apply_background, camera),
                on_start_error=self._run_without_background))
        self.entrance = Entrance(
            self.parameters.dataclass(AdmissionParams(), prefix='admission.',
                                      apply=lambda params: self.entrance.set_params(params)),
            last_stage_reports=self._last_stage_reports,
            middle_reports=self._middle_stages_report,
            take=lambda views: self.take_frame(views), reopen=self.reopen_inputs,
            threaded=self.sync_params.worker_thread, spare_cores=self.spare_cpu.cores,
            camera_period_s=lambda: None if self._inputs is None else self._inputs.frame_period_s,
            stages=1 + len(DOWNSTREAM))
        self._downstream = {
            stage: self.create_subscription(
                message_class('std_msgs/msg/Header'), outcome_topic(stage),
                lambda msg, stage=stage: self._on_downstream_outcome(stage, msg), RESULT_QOS)
            for stage in DOWNSTREAM}
        self.relay = FrameRelay(self, self.cameras)
        self.status.extras.append(lambda: self._rig_status)   # a snapshot the frame thread made
        self._label_publishers = {
            camera: self.create_publisher(message_class(IMAGE),
                                          node_relative(labels_topic(camera)), RESULT_QOS)
            for camera in self.cameras}
        self.start_when_ready(self._warm_up, camera_inputs(CAMERA_INPUTS))

    def _on_downstream_outcome(self, stage: str, msg: Any) -> None:
        """A later stage's outcome of a frame, for the entrance."""
        try:
            stamp_ns, outcome = read_frame_outcome(msg)
        except ValueError as error:
            self.get_logger().warning(f'{outcome_topic(stage)}: {error}',
                                      throttle_duration_sec=5.0)
            return
        self.entrance.finished_downstream(stamp_ns, outcome, last_stage=stage == DOWNSTREAM[-1])

    @property
    def in_flight(self) -> InFlightFrames:
        """The frames the entrance admitted that are still unfinished downstream."""
        return self.entrance.in_flight

    def _last_stage_reports(self) -> bool:
        """Whether the last stage (the pose estimator) publishes its outcomes now."""
        return self._downstream[DOWNSTREAM[-1]].get_publisher_count() > 0

    def _middle_stages_report(self) -> bool:
        """Whether every stage between this one and the last publishes its outcomes
        (``admission.pipeline_behind_last_stage``)."""
        return all(self._downstream[stage].get_publisher_count() > 0
                   for stage in DOWNSTREAM[:-1])

    def _warm_up(self) -> None:
        """Segment and fuse a synthetic frame once, and estimate a rig from it (first calls,
        lazy imports); the estimate is thrown away."""
        views, _ = self.warm_up_frame(self.backgrounds)
        pipeline = self._pipeline(views, self._configured_rig(views))
        pipeline.localise(views)
        if len(views) > 1:
            RigRefiner(pipeline.rig).observe({c: v.depth_m for c, v in views.items()})

    def _configured_rig(self, views: dict[str, ViewInput]) -> Rig:
        return rig_with_intrinsics(self.extrinsics, {c: v.intrinsics for c, v in views.items()})

    def _pipeline(self, views: dict[str, ViewInput], rig: Rig) -> PerceptionPipeline:
        """The frame's pipeline with ``rig``; each view is read with its camera's pose."""
        for camera, view in views.items():
            view.T_world_camera = rig[camera].T_world_camera
        return PerceptionPipeline(rig=rig, segmentation=self.segmentation, fusion=self.fusion,
                                  part_extents_m=self.part_extents_m,
                                  localise_params=replace(
                                      self.localise_params,
                                      parallel_views=self._views_in_parallel))

    def _refined_pipeline(self, views: dict[str, ViewInput]) -> PerceptionPipeline:
        """The frame's pipeline, its rig checked against (and, with ``rig_refinement.mode``
        'use', refined from) the table planes and parts the cameras see, this frame
        included. A rig of one camera has nothing to refine against: it keeps its own."""
        configured = self._configured_rig(views)
        if self.rig_refinement.mode == 'none' or len(self.cameras) < 2:
            self.refiner, self._rig_status = None, ('', {'rig_refinement': 'none'})
            self._publish_rig(configured, configured)
            return self._pipeline(views, configured)
        if self.refiner is None or not same_rig(self.refiner.prior, configured):
            self.refiner = RigRefiner(configured, self.rig_refinement)
        pipeline = refined_pipeline(self.refiner, views, partial(self._pipeline, views))
        self._publish_rig(self.refiner.rig, configured)
        status = self.refiner.status()
        self._rig_status = (status.message if status.warn else '', status.values)
        return pipeline

    def _publish_rig(self, rig: Rig, configured: Rig) -> None:
        """Tell the later stages (``rig_source`` 'localiser') the camera poses the fusion
        uses when they change: nothing goes out while the configured rig is kept."""
        if same_rig(rig, self._published_rig or configured):
            return
        self._published_rig = rig
        self._rig_publisher.publish(camera_poses_to_pose_array(
            {c: rig[c].T_world_camera for c in CAMERA_NAMES}, names=CAMERA_NAMES,
            frame_id=rig.world_frame, factory=self._rig_factory))

    def _apply_rig_refinement(self, params: RigRefinementParams) -> None:
        self.rig_refinement = params
        if self.refiner is not None:
            self.refiner.set_params(params)

    def _run_without_background(self, error: Exception) -> None:
        self.get_logger().error(f'{error}; not using it')   # the node runs without it

    def _apply_segmentation(self, params: SegmentationParams) -> None:
        """New segmentation settings; the empty-table images are prepared again for them
        (their colour cues depend on ``cue_scale`` and ``hed_dark_level``)."""
        self.segmentation = params
        self.backgrounds = {camera: prepare_background(rgb, params=params)
                            for camera, rgb in self._empty_tables.items()}

    def _apply_background(self, camera: str, rgb: np.ndarray | None) -> None:
        """Use the empty-table image ``rgb`` for ``camera`` (None: no background)."""
        tables = {c: image for c, image in self._empty_tables.items() if c != camera}
        backgrounds = {c: model for c, model in self.backgrounds.items() if c != camera}
        if rgb is not None:
            tables[camera] = rgb
            backgrounds[camera] = prepare_background(rgb, params=self.segmentation)
        self._empty_tables, self.backgrounds = tables, backgrounds

    def process(self, views: dict[str, dict[str, Any]]) -> None:
        inputs = {camera: self._view_input(camera, msgs) for camera, msgs in views.items()}
        # two threads only while a core was free beside this stage's work, or idle, lately
        # (parallel.min_spare_cores)
        with self.spare_cpu.work(self.localise_params.parallel_views) as split:
            self._views_in_parallel = split
            fusion = self._refined_pipeline(inputs).localise(inputs)
        admission = {'views_in_parallel': int(self._views_in_parallel),
                     **self.entrance.stats()}
        self.record_stats({**{f'{k}_ms': v for k, v in fusion.timings_ms.items()}, **admission,
                           **self.spare_cpu.stats()})
        for camera, msgs in views.items():
            header = msgs['color'].header
            self._label_publishers[camera].publish(image_to_cdr(   # raw CDR: one copy
                fusion.labels[camera], '16UC1', frame_id=header.frame_id,
                stamp_ns=stamp_to_ns(header.stamp)))

    def _view_input(self, camera: str, msgs: dict[str, Any]) -> ViewInput:
        intrinsics = camera_info_to_intrinsics(msgs['info'])
        rgb = image_to_rgb(msgs['color'])
        if rgb.shape[:2] != (intrinsics.height, intrinsics.width):
            raise ValueError(f'{camera}: colour is {rgb.shape[1]}x{rgb.shape[0]} but '
                             f'CameraInfo says {intrinsics.width}x{intrinsics.height}')
        return ViewInput(rgb=rgb, depth_m=depth_image_to_metres(msgs['depth']),
                         intrinsics=intrinsics, T_world_camera=self.extrinsics[camera],
                         background=self.backgrounds.get(camera))


class FrameRelay:
    """Passes the camera messages of each frame the localiser takes, as received, to the later
    stages (``input_source: localiser``): ``/localiser/<camera>/...``."""

    def __init__(self, node: Any, cameras: tuple[str, ...]) -> None:
        self._publishers = {camera: {
            key: node.create_publisher(message_class(msg_type), relay_topic(camera, topic),
                                       RESULT_QOS)
            for key, (msg_type, topic) in CAMERA_INPUTS.items()} for camera in cameras}

    def publish(self, views: Views) -> None:
        """Relay a taken frame to the stages subscribed to it."""
        for camera, msgs in views.items():
            for key, raw in msgs.items():
                publisher = self._publishers[camera][key]
                if publisher.get_subscription_count() > 0:
                    publisher.publish(raw.data)   # CDR bytes: no copy into a Python message


def same_rig(a: Rig, b: Rig) -> bool:
    """Whether two rigs have the same cameras, poses and camera matrices."""
    return a.cameras.keys() == b.cameras.keys() and all(
        np.array_equal(a[c].T_world_camera, b[c].T_world_camera) and
        np.array_equal(a[c].intrinsics.K, b[c].intrinsics.K) for c in a.cameras)


def read_empty_table(path: str) -> np.ndarray | None:
    """The (H, W, 3) uint8 RGB image at ``path`` ('' = none: None).

    Raises:
        TlessbotError: the file cannot be read as an image.
    """
    if not path:
        return None
    bgr = cv2.imread(path, cv2.IMREAD_COLOR)
    if bgr is None:
        raise TlessbotError(f'cannot read background image {path!r}')
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def main(args: list[str] | None = None) -> None:
    run_node(LocaliserNode, args)


if __name__ == '__main__':
    main()
