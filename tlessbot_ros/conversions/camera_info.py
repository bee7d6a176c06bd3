"""sensor_msgs/CameraInfo <-> :class:`~tlessbot_ros.core.common.CameraIntrinsics`."""
from __future__ import annotations

from typing import Any

import numpy as np

from tlessbot_ros.conversions.messages import MessageFactory, default_factory, make_header
from tlessbot_ros.core.common import CameraIntrinsics, RegionOfInterest


def camera_info_to_intrinsics(msg: Any) -> CameraIntrinsics:
    """Read K, D, size, distortion model and ROI of a CameraInfo.

    Raises:
        ValueError: zero image size, or a K with non-positive focal lengths (an unset
            CameraInfo has K = 0).
    """
    K = np.asarray(msg.k, dtype=np.float64)
    if K.size != 9:
        raise ValueError(f'CameraInfo.k must have 9 elements, got {K.size}')
    if int(msg.width) == 0 or int(msg.height) == 0:
        raise ValueError('CameraInfo has zero image size; is the camera calibrated?')
    roi = msg.roi
    return CameraIntrinsics(
        width=int(msg.width),
        height=int(msg.height),
        K=K.reshape(3, 3),
        D=np.asarray(msg.d, dtype=np.float64),
        distortion_model=str(msg.distortion_model) or 'plumb_bob',
        roi=RegionOfInterest(int(roi.x_offset), int(roi.y_offset), int(roi.width),
                             int(roi.height), bool(roi.do_rectify)),
    )


def intrinsics_to_camera_info(
    intrinsics: CameraIntrinsics,
    *,
    frame_id: str = '',
    stamp_ns: int = 0,
    factory: MessageFactory | None = None,
) -> Any:
    """CameraInfo of an unrectified, already undistorted-or-not stream: R = I, P = [K | 0]."""
    factory = factory or default_factory()
    P = np.zeros((3, 4))
    P[:, :3] = intrinsics.K
    roi = intrinsics.roi
    return factory.new(
        'sensor_msgs/msg/CameraInfo',
        header=make_header(frame_id, stamp_ns, factory),
        height=intrinsics.height,
        width=intrinsics.width,
        distortion_model=intrinsics.distortion_model,
        d=factory.float64_array(intrinsics.D),
        k=factory.float64_array(intrinsics.K),
        r=factory.float64_array(np.eye(3)),
        p=factory.float64_array(P),
        roi=factory.new('sensor_msgs/msg/RegionOfInterest', x_offset=roi.x_offset,
                        y_offset=roi.y_offset, width=roi.width, height=roi.height,
                        do_rectify=roi.do_rectify),
    )
