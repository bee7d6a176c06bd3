"""localiser: segments the top and side colour images and fuses them into instance labels.

Subscribes (sensor-data QoS), for CAMERA in top, side:
    /CAMERA/color/image_raw                      sensor_msgs/Image (rgb8, bgr8, ...)
    /CAMERA/aligned_depth_to_color/image_raw     sensor_msgs/Image (16UC1 mm or 32FC1 m)
    /CAMERA/aligned_depth_to_color/camera_info   sensor_msgs/CameraInfo
Publishes (RELIABLE, depth 10):
    localiser/CAMERA/labels   sensor_msgs/Image 16UC1: 0 = background, 1..N instances; the same
                              id marks the same part in both views (header = colour header)
    /diagnostics              frames, failures, dropped, latency, stage times
Parameters: ``parallel_views`` (segment both views at once, in two threads),
``segmentation.*`` (SegmentationParams), ``fusion.*`` (FusionParams: method calibrated |
algorithm1 | side_only), ``sync.*`` (SyncParams), ``rig.CAMERA.*`` (extrinsics),
``background.CAMERA`` (path of an empty-table PNG for background subtraction; '' = none).
Frames: outputs keep each source image's frame and stamp.
"""
from __future__ import annotations

import dataclasses
from typing import Any

import cv2

from tlessbot_ros.conversions import (
    camera_info_to_intrinsics,
    depth_image_to_metres,
    image_to_rgb,
    stamp_to_ns,
)
from tlessbot_ros.conversions.image_cdr import image_to_cdr
from tlessbot_ros.core.localise import FusionParams, SegmentationParams, prepare_background
from tlessbot_ros.core.pipeline import PerceptionPipeline, PipelineParams, ViewInput
from tlessbot_ros.nodes.common import RESULT_QOS, declare_from_dataclass, message_class, run_node
from tlessbot_ros.nodes.stage import (
    CAMERAS,
    StageNode,
    declare_extrinsics,
    descriptor,
    rig_with_intrinsics,
)

IMAGE = 'sensor_msgs/msg/Image'


class LocaliserNode(StageNode):
    """Segmentation + two-view fusion -> instance label images."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('localiser', **kwargs)
        self.segmentation = dataclasses.replace(SegmentationParams(), **declare_from_dataclass(
            self, SegmentationParams(), prefix='segmentation.'))
        self.fusion = dataclasses.replace(FusionParams(), **declare_from_dataclass(
            self, FusionParams(), prefix='fusion.'))
        self.parallel_views = bool(self.declare_parameter(
            'parallel_views', PipelineParams().parallel_views, descriptor(
                'segment the top and side images at once, in two threads')).value)
        self.extrinsics = declare_extrinsics(self)
        self.backgrounds = {}
        for camera in CAMERAS:
            path = self.declare_parameter(f'background.{camera}', '').value
            if path:
                self.backgrounds[camera] = self._load_background(path)
        self._label_publishers = {
            camera: self.create_publisher(message_class(IMAGE), f'localiser/{camera}/labels',
                                          RESULT_QOS) for camera in CAMERAS}
        self.setup_inputs({
            'color': (IMAGE, '/{camera}/color/image_raw'),
            'depth': (IMAGE, '/{camera}/aligned_depth_to_color/image_raw'),
            'info': ('sensor_msgs/msg/CameraInfo', '/{camera}/aligned_depth_to_color/camera_info'),
        })

    def _load_background(self, path: str) -> Any:
        bgr = cv2.imread(path, cv2.IMREAD_COLOR)
        if bgr is None:
            self.get_logger().error(f'cannot read background image {path!r}; not using it')
            return None
        return prepare_background(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB),
                                  params=self.segmentation)

    def process(self, views: dict[str, dict[str, Any]]) -> None:
        inputs = {}
        for camera, msgs in views.items():
            intrinsics = camera_info_to_intrinsics(msgs['info'])
            rgb = image_to_rgb(msgs['color'])
            if rgb.shape[:2] != (intrinsics.height, intrinsics.width):
                raise ValueError(f'{camera}: colour is {rgb.shape[1]}x{rgb.shape[0]} but '
                                 f'CameraInfo says {intrinsics.width}x{intrinsics.height}')
            inputs[camera] = ViewInput(rgb=rgb, depth_m=depth_image_to_metres(msgs['depth']),
                                       intrinsics=intrinsics,
                                       T_world_camera=self.extrinsics[camera],
                                       background=self.backgrounds.get(camera))
        rig = rig_with_intrinsics(self.extrinsics, {c: v.intrinsics for c, v in inputs.items()})
        pipeline = PerceptionPipeline(rig=rig, segmentation=self.segmentation, fusion=self.fusion,
                                      params=PipelineParams(parallel_views=self.parallel_views))
        fusion = pipeline.localise(inputs)
        self.record_stats({f'{k}_ms': v for k, v in fusion.timings_ms.items()})
        for camera, msgs in views.items():
            header = msgs['color'].header
            self._label_publishers[camera].publish(image_to_cdr(   # raw CDR: one copy
                fusion.labels[camera], '16UC1', frame_id=header.frame_id,
                stamp_ns=stamp_to_ns(header.stamp)))


def main(args: list[str] | None = None) -> None:
    run_node(LocaliserNode, args)


if __name__ == '__main__':
    main()
