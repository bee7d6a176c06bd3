"""One RGB-D camera frame as the realsense-ros set of messages.

Topic names (:mod:`~tlessbot_ros.conversions.topics`) are relative to the camera's namespace
(``/top``, ``/side``) and follow realsense-ros with ``align_depth.enable:=true
pointcloud.enable:=true``. Everything is in
``<camera>_color_optical_frame``, stamped with the frame's stamp.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from tlessbot_ros.conversions.camera_info import intrinsics_to_camera_info
from tlessbot_ros.conversions.image import array_to_image
from tlessbot_ros.conversions.messages import MessageFactory, default_factory
from tlessbot_ros.conversions.pointcloud import xyz_to_pointcloud2
from tlessbot_ros.conversions.topics import COLOR, COLOR_INFO, DEPTH, DEPTH_INFO, POINTS
from tlessbot_ros.core.common import CameraIntrinsics, depth_to_points


def optical_frame(camera_name: str) -> str:
    """realsense-ros colour optical frame of a camera."""
    return f'{camera_name}_color_optical_frame'


def camera_frame_messages(
    camera_name: str,
    rgb: np.ndarray,
    depth_mm: np.ndarray,
    intrinsics: CameraIntrinsics,
    stamp_ns: int,
    *,
    with_cloud: bool = True,
    cloud_stride: int = 1,
    factory: MessageFactory | None = None,
) -> dict[str, Any]:
    """Messages of one aligned RGB-D frame, keyed by relative topic name.

    Args:
        rgb: (H, W, 3) uint8 RGB colour image.
        depth_mm: (H, W) uint16 depth aligned to colour, millimetres, 0 = invalid.
        intrinsics: colour intrinsics (also those of the aligned depth).
        stamp_ns: the frame's capture time in ROS time, nanoseconds.
        with_cloud: add ``depth/color/points`` (x, y, z + rgb of every valid pixel).
        cloud_stride: use every n-th row and column for the cloud (1 = all pixels).
    """
    if rgb.shape[:2] != depth_mm.shape or rgb.shape[:2] != (intrinsics.height,
                                                             intrinsics.width):
        raise ValueError(f'colour {rgb.shape[:2]}, depth {depth_mm.shape} and intrinsics '
                         f'{intrinsics.height}x{intrinsics.width} sizes must agree')
    factory = factory or default_factory()
    frame = optical_frame(camera_name)
    info = intrinsics_to_camera_info(intrinsics, frame_id=frame, stamp_ns=stamp_ns,
                                     factory=factory)
    messages = {
        COLOR: array_to_image(rgb, 'rgb8', frame_id=frame, stamp_ns=stamp_ns,
                                    factory=factory),
        COLOR_INFO: info,
        DEPTH: array_to_image(depth_mm, '16UC1', frame_id=frame, stamp_ns=stamp_ns,
                                    factory=factory),
        DEPTH_INFO: intrinsics_to_camera_info(intrinsics, frame_id=frame,
                                                    stamp_ns=stamp_ns, factory=factory),
    }
    if with_cloud:
        mask = np.zeros(depth_mm.shape, bool)
        mask[::cloud_stride, ::cloud_stride] = True
        depth_m = depth_mm.astype(np.float32) * np.float32(0.001)
        xyz, pixels = depth_to_points(depth_m, intrinsics.K, mask=mask)
        colours = rgb[pixels[:, 0], pixels[:, 1]]
        messages[POINTS] = xyz_to_pointcloud2(xyz, colours, frame_id=frame,
                                                    stamp_ns=stamp_ns, factory=factory)
    return messages
