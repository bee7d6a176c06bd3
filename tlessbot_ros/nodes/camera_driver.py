"""camera_driver: one Intel RealSense D415 -> the realsense-ros topics. Launched once per camera.

Run: ``ros2 run tlessbot_ros camera_driver --ros-args -r __ns:=/top -p camera_name:=top
-p serial_no:=_123456789`` (a leading ``_`` keeps the serial a string, as in realsense-ros).

Publishes (relative to the namespace, RELIABLE, depth 10):
    color/image_raw                        sensor_msgs/Image, rgb8
    color/camera_info                      sensor_msgs/CameraInfo
    aligned_depth_to_color/image_raw       sensor_msgs/Image, 16UC1 (mm, 0 = invalid)
    aligned_depth_to_color/camera_info     sensor_msgs/CameraInfo
    depth/color/points                     sensor_msgs/PointCloud2 (x y z + rgb), if pointcloud
    /diagnostics                           diagnostic_msgs/DiagnosticArray, 1 Hz: OK / ERROR
Frames: ``<camera_name>_color_optical_frame``. Stamps: ROS time at capture. The point cloud is
built only while it has a subscriber.
Parameters: see :class:`tlessbot_ros.sensors.realsense.RealSenseParams`. ``cloud_stride``,
``reconnect`` and ``reconnect_period_s`` are live (``ros2 param set``, at once); the device and
stream ones (``READ_ONLY``) are read-only.
With no device, or when the device is lost, the node reports ERROR and retries every
``reconnect_period_s``; it never exits for that.
"""
from __future__ import annotations

import threading
from functools import partial
from typing import Any

from rclpy.node import Node

from tlessbot_ros.conversions.camera import camera_frame_messages
from tlessbot_ros.conversions.messages import RclpyFactory
from tlessbot_ros.conversions.topics import (
    CAMERA_TOPICS,
    COLOR,
    COLOR_INFO,
    DEPTH,
    DEPTH_INFO,
    DIAGNOSTICS,
    POINTS,
)
from tlessbot_ros.errors import DeviceError
from tlessbot_ros.nodes.common import RESULT_QOS, message_class, run_node
from tlessbot_ros.nodes.diagnostics import ERROR, OK, diagnostic_array
from tlessbot_ros.nodes.exit_wait import wait_at_exit
from tlessbot_ros.nodes.parameters import AT_ONCE, LiveParameters
from tlessbot_ros.sensors.realsense import RealSenseCamera, RealSenseParams

DESCRIPTIONS = {
    'serial_no': 'Serial number of the device (leading _ allowed); empty = first device',
    'camera_name': 'Camera name: frames are <camera_name>_color_optical_frame',
    'width': 'Colour and depth width in pixels',
    'height': 'Colour and depth height in pixels',
    'fps': 'Frame rate of both streams',
    'align_depth': 'Align depth to colour (required by the perception graph)',
    'pointcloud': 'Publish depth/color/points',
    'cloud_stride': 'Pixel stride of the published point cloud (1 = every valid pixel)',
    'reconnect': 'Retry when the device is missing or lost',
    'reconnect_period_s': 'Seconds between reconnection attempts',
    'frame_timeout_ms': 'Frame wait before the device counts as lost, in milliseconds',
}
# The stream, its frames and its topics are set when the device opens; the rest is live (the
# capture loop reads it once per frame).
READ_ONLY = ('serial_no', 'camera_name', 'width', 'height', 'fps', 'align_depth', 'pointcloud',
             'frame_timeout_ms')
TOPIC_TYPES = {
    COLOR: 'sensor_msgs/msg/Image', COLOR_INFO: 'sensor_msgs/msg/CameraInfo',
    DEPTH: 'sensor_msgs/msg/Image', DEPTH_INFO: 'sensor_msgs/msg/CameraInfo',
    POINTS: 'sensor_msgs/msg/PointCloud2',
}


class CameraDriverNode(Node):
    """Streams one RealSense device; survives its absence and loss."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('camera_driver', **kwargs)
        self.parameters = LiveParameters(self)
        self.params = self.parameters.dataclass(
            RealSenseParams(), descriptions=DESCRIPTIONS, when=AT_ONCE, read_only=READ_ONLY,
            ranges={'fps': (1, 90), 'cloud_stride': (1, 16)},
            apply=partial(setattr, self, 'params'))
        self._factory = RclpyFactory()
        self._camera_publishers = {topic: self.create_publisher(message_class(TOPIC_TYPES[topic]),
                                                         topic, RESULT_QOS)
                            for topic in CAMERA_TOPICS
                            if topic != POINTS or self.params.pointcloud}
        self._diagnostics = self.create_publisher(message_class(
            'diagnostic_msgs/msg/DiagnosticArray'), DIAGNOSTICS, RESULT_QOS)
        self._camera = RealSenseCamera(self.params)
        self._status = (ERROR, 'starting')
        self.frames_published = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._capture_loop, daemon=True)
        self.create_timer(1.0, self._publish_diagnostics)
        self._thread.start()
        wait_at_exit(self._thread, stop=self._stop.set)   # it reads in pyrealsense2's C++

    def _capture_loop(self) -> None:
        """Open, read and publish until shutdown; on DeviceError report and retry."""
        while not self._stop.is_set():
            try:
                if not self._camera.is_open:
                    self._camera.open()
                    self.get_logger().info(f'streaming {self.params.width}x{self.params.height}'
                                           f' @ {self.params.fps} fps')
                self.publish_frame(self._camera.read())
                self._status = (OK, 'streaming')
            except DeviceError as error:
                self._status = (ERROR, str(error))
                self.get_logger().error(f'{error}; retrying every '
                                        f'{self.params.reconnect_period_s} s',
                                        throttle_duration_sec=10.0)
                if not self.params.reconnect:
                    return
                self._stop.wait(self.params.reconnect_period_s)

    def publish_frame(self, frame: Any) -> None:
        """Publish one aligned RealSenseFrame, stamped with the ROS time now."""
        stamp_ns = self.get_clock().now().nanoseconds
        # The cloud costs ~10 ms in Python at 640x480: build it only while someone listens.
        cloud_publisher = self._camera_publishers.get(POINTS)
        with_cloud = cloud_publisher is not None and cloud_publisher.get_subscription_count() > 0
        messages = camera_frame_messages(
            self.params.camera_name, frame.rgb, frame.depth_mm, frame.intrinsics, stamp_ns,
            with_cloud=with_cloud, cloud_stride=self.params.cloud_stride, factory=self._factory)
        for topic, msg in messages.items():
            self._camera_publishers[topic].publish(msg)
        self.frames_published += 1

    def _publish_diagnostics(self) -> None:
        level, message = self._status
        self._diagnostics.publish(diagnostic_array(
            self.get_clock().now().to_msg(), f'{self.get_name()}: {self.params.camera_name}',
            level, message, {'serial_no': self.params.serial_no or 'any',
                             'frames_published': self.frames_published},
            hardware_id=self.params.serial_no))

    def destroy_node(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._camera.close()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    run_node(CameraDriverNode, args)


if __name__ == '__main__':
    main()
