"""Intel RealSense access through pyrealsense2 (imported lazily), plus the device-free pieces.

:class:`RealSenseCamera` opens one device by serial number with colour and depth streams at the
same size and rate and aligns depth to colour (``rs.align``), as realsense-ros does with
``align_depth.enable:=true``. :func:`depth_to_mm` and :func:`intrinsics_from_rs` are pure and
tested without a device.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics
from tlessbot_ros.errors import DeviceError


@dataclass(frozen=True)
class RealSenseParams:
    """Driver settings (ROS parameters of ``camera_driver``).

    Attributes:
        serial_no: device serial number (a leading ``_`` is dropped); empty = the first
            device found.
        camera_name: prefix of the frames (``<name>_color_optical_frame``).
        width, height, fps: colour and depth stream profile.
        align_depth: align depth to colour (the graph needs it).
        pointcloud: publish ``depth/color/points``.
        cloud_stride: pixel stride of the published cloud (1 = every valid pixel).
        reconnect: retry when the device is missing or lost.
        reconnect_period_s: seconds between retries.
        frame_timeout_ms: how long to wait for a frame before declaring the device lost.
    """

    serial_no: str = ''
    camera_name: str = 'camera'
    width: int = 640
    height: int = 480
    fps: int = 30
    align_depth: bool = True
    pointcloud: bool = True
    cloud_stride: int = 1
    reconnect: bool = True
    reconnect_period_s: float = 2.0
    frame_timeout_ms: int = 1000

    def __post_init__(self) -> None:
        # realsense-ros's convention: a leading '_' keeps a numeric serial a string in YAML
        object.__setattr__(self, 'serial_no', str(self.serial_no).lstrip('_'))
        if not self.reconnect_period_s > 0:
            raise ValueError(f'reconnect_period_s must be > 0 s, got {self.reconnect_period_s}')
        if self.cloud_stride < 1 or self.frame_timeout_ms < 1:
            raise ValueError(f'cloud_stride and frame_timeout_ms must be >= 1, got '
                             f'{self.cloud_stride} and {self.frame_timeout_ms}')


@dataclass
class RealSenseFrame:
    """One aligned frame: (H, W, 3) uint8 RGB, (H, W) uint16 depth in mm (0 = invalid)."""

    rgb: np.ndarray
    depth_mm: np.ndarray
    intrinsics: CameraIntrinsics


def depth_to_mm(depth_raw: np.ndarray, depth_scale_m: float) -> np.ndarray:
    """Device depth units to millimetres (uint16, 0 stays invalid), like realsense-ros.

    The D415 reports 1 mm units (scale 0.001) by default; other presets use other scales.
    """
    if depth_scale_m <= 0:
        raise ValueError(f'depth scale must be positive, got {depth_scale_m}')
    depth_raw = np.asarray(depth_raw)
    if np.isclose(depth_scale_m, 0.001):
        return depth_raw.astype(np.uint16, copy=False)
    mm = np.rint(depth_raw.astype(np.float64) * (depth_scale_m * 1000.0))
    return np.clip(mm, 0, 65535).astype(np.uint16)


def intrinsics_from_rs(rs_intrinsics: Any) -> CameraIntrinsics:
    """CameraIntrinsics of a ``pyrealsense2.intrinsics`` (width, height, fx, fy, ppx, ppy,
    coeffs, model). Brown-Conrady maps to plumb_bob."""
    K = np.array([[rs_intrinsics.fx, 0.0, rs_intrinsics.ppx],
                  [0.0, rs_intrinsics.fy, rs_intrinsics.ppy], [0.0, 0.0, 1.0]])
    model = str(getattr(rs_intrinsics, 'model', '')).lower()
    distortion = 'equidistant' if 'kannala' in model or 'equidistant' in model else 'plumb_bob'
    return CameraIntrinsics(width=int(rs_intrinsics.width), height=int(rs_intrinsics.height),
                            K=K, D=np.asarray(list(rs_intrinsics.coeffs), dtype=np.float64),
                            distortion_model=distortion)


def connected_serials() -> list[str]:
    """Serial numbers of the connected RealSense devices (empty without pyrealsense2)."""
    try:
        import pyrealsense2 as rs
    except ImportError:
        return []
    return [device.get_info(rs.camera_info.serial_number)
            for device in rs.context().query_devices()]


class RealSenseCamera:
    """One D4xx device streaming aligned colour + depth."""

    def __init__(self, params: RealSenseParams) -> None:
        self.params = params
        self._pipeline: Any = None
        self._align: Any = None
        self._depth_scale = 0.001

    @property
    def is_open(self) -> bool:
        return self._pipeline is not None

    def open(self) -> None:
        """Start streaming; raises :class:`DeviceError` when the device is absent or busy."""
        try:
            import pyrealsense2 as rs
        except ImportError:
            raise DeviceError('pyrealsense2 is not installed') from None
        serials = connected_serials()
        if not serials:
            raise DeviceError('no RealSense device connected')
        if self.params.serial_no and self.params.serial_no not in serials:
            raise DeviceError(f'RealSense {self.params.serial_no} not found; connected: '
                              f'{serials}')
        p = self.params
        config = rs.config()
        if p.serial_no:
            config.enable_device(p.serial_no)
        config.enable_stream(rs.stream.color, p.width, p.height, rs.format.rgb8, p.fps)
        config.enable_stream(rs.stream.depth, p.width, p.height, rs.format.z16, p.fps)
        pipeline = rs.pipeline()
        try:
            profile = pipeline.start(config)
        except RuntimeError as error:
            raise DeviceError(f'cannot start RealSense streams: {error}') from None
        self._depth_scale = profile.get_device().first_depth_sensor().get_depth_scale()
        self._align = rs.align(rs.stream.color) if p.align_depth else None
        self._pipeline = pipeline

    def read(self) -> RealSenseFrame:
        """Wait for the next frame set; raises :class:`DeviceError` if none arrives in time."""
        if self._pipeline is None:
            raise DeviceError('camera is not open')
        try:
            frames = self._pipeline.wait_for_frames(self.params.frame_timeout_ms)
            if self._align is not None:
                frames = self._align.process(frames)
            color, depth = frames.get_color_frame(), frames.get_depth_frame()
        except RuntimeError as error:
            self.close()
            raise DeviceError(f'RealSense stopped delivering frames: {error}') from None
        if not color or not depth:
            raise DeviceError('incomplete frame set (colour or depth missing)')
        intrinsics = intrinsics_from_rs(color.profile.as_video_stream_profile().intrinsics)
        return RealSenseFrame(rgb=np.asanyarray(color.get_data()).copy(),
                              depth_mm=depth_to_mm(np.asanyarray(depth.get_data()),
                                                   self._depth_scale),
                              intrinsics=intrinsics)

    def close(self) -> None:
        if self._pipeline is not None:
            try:
                self._pipeline.stop()
            except RuntimeError:
                pass
        self._pipeline = None
