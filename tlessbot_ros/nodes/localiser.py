"""localiser: segments the top and side colour images and fuses them into instance labels.

Subscribes (sensor-data QoS), for CAMERA in top, side:
    /CAMERA/color/image_raw                      sensor_msgs/Image (rgb8, bgr8, ...)
    /CAMERA/aligned_depth_to_color/image_raw     sensor_msgs/Image (16UC1 mm or 32FC1 m)
    /CAMERA/aligned_depth_to_color/camera_info   sensor_msgs/CameraInfo
Publishes (RELIABLE, depth 10):
    localiser/CAMERA/labels   sensor_msgs/Image 16UC1: 0 = background, 1..N instances; the same
                              id marks the same part in both views (header = colour header)
    /diagnostics              frames, failures, dropped, latency, stage times
Parameters: ``parallel_views`` (LocaliseParams: segment both views at once, in two threads),
``segmentation.*`` (SegmentationParams), ``fusion.*`` (FusionParams: method calibrated |
algorithm1 | side_only), ``sync.*`` (SyncParams), ``rig.cameras`` (the names of the top and
side cameras), ``rig.CAMERA.*`` (extrinsics), ``background.CAMERA`` (path of an empty-table
PNG for background subtraction; '' = none).
Frames: outputs keep each source image's frame and stamp.
"""
from __future__ import annotations

from typing import Any

import cv2

from tlessbot_ros.conversions import (
    camera_info_to_intrinsics,
    depth_image_to_metres,
    image_to_rgb,
    stamp_to_ns,
)
from tlessbot_ros.conversions.image_cdr import image_to_cdr
from tlessbot_ros.conversions.topics import labels_topic, node_relative
from tlessbot_ros.core.localise import FusionParams, SegmentationParams, prepare_background
from tlessbot_ros.core.pipeline import LocaliseParams, PerceptionPipeline, ViewInput
from tlessbot_ros.nodes.common import RESULT_QOS, message_class, params_from_node, run_node
from tlessbot_ros.nodes.stage import (
    COLOR_INPUT,
    DEPTH_INPUTS,
    IMAGE,
    StageNode,
    rig_with_intrinsics,
)


class LocaliserNode(StageNode):
    """Segmentation + two-view fusion -> instance label images."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('localiser', **kwargs)
        self.segmentation = params_from_node(self, SegmentationParams, prefix='segmentation.')
        self.fusion = params_from_node(self, FusionParams, prefix='fusion.')
        self.localise_params = params_from_node(self, LocaliseParams)
        self.backgrounds = {}
        for camera in self.cameras:
            path = self.declare_parameter(f'background.{camera}', '').value
            if path:
                self.backgrounds[camera] = self._load_background(path)
        self._label_publishers = {
            camera: self.create_publisher(message_class(IMAGE),
                                          node_relative(labels_topic(camera)), RESULT_QOS)
            for camera in self.cameras}
        self.start_when_ready(self._warm_up, {'color': COLOR_INPUT, **DEPTH_INPUTS})

    def _warm_up(self) -> None:
        """Segment and fuse a synthetic frame once (first calls, lazy imports)."""
        views, _ = self.warm_up_frame(self.backgrounds)
        self._pipeline(views).localise(views)

    def _pipeline(self, views: dict[str, ViewInput]) -> PerceptionPipeline:
        rig = rig_with_intrinsics(self.extrinsics, {c: v.intrinsics for c, v in views.items()})
        return PerceptionPipeline(rig=rig, segmentation=self.segmentation, fusion=self.fusion,
                                  localise_params=self.localise_params)

    def _load_background(self, path: str) -> Any:
        bgr = cv2.imread(path, cv2.IMREAD_COLOR)
        if bgr is None:
            self.get_logger().error(f'cannot read background image {path!r}; not using it')
            return None
        return prepare_background(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB),
                                  params=self.segmentation)

    def process(self, views: dict[str, dict[str, Any]]) -> None:
        inputs = {camera: self._view_input(camera, msgs) for camera, msgs in views.items()}
        fusion = self._pipeline(inputs).localise(inputs)
        self.record_stats({f'{k}_ms': v for k, v in fusion.timings_ms.items()})
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


def main(args: list[str] | None = None) -> None:
    run_node(LocaliserNode, args)


if __name__ == '__main__':
    main()
