"""ROS message <-> numpy conversions.

Duck-typed: every reader works on rclpy messages and on rosbags dataclasses alike (same field
names), and never checks ``isinstance`` against a message class. Builders create messages through
a :class:`~tlessbot_ros.conversions.messages.MessageFactory`, rclpy's by default, imported lazily,
so importing this package never needs rclpy.
"""
from tlessbot_ros.conversions.camera_info import (
    camera_info_to_intrinsics,
    intrinsics_to_camera_info,
)
from tlessbot_ros.conversions.image import (
    array_to_image,
    depth_image_to_metres,
    image_to_array,
    image_to_rgb,
)
from tlessbot_ros.conversions.messages import (
    MessageFactory,
    RclpyFactory,
    RosbagsFactory,
    make_header,
    ns_to_stamp,
    stamp_to_ns,
)
from tlessbot_ros.conversions.pointcloud import (
    depth_image_to_pointcloud2,
    pointcloud2_to_xyz,
    xyz_to_pointcloud2,
)
from tlessbot_ros.conversions.pose import pose_stamped_to_transform, transform_to_pose_stamped

__all__ = [
    'MessageFactory', 'RclpyFactory', 'RosbagsFactory', 'make_header', 'ns_to_stamp',
    'stamp_to_ns', 'image_to_array', 'image_to_rgb', 'array_to_image', 'depth_image_to_metres',
    'camera_info_to_intrinsics', 'intrinsics_to_camera_info', 'pointcloud2_to_xyz',
    'xyz_to_pointcloud2', 'depth_image_to_pointcloud2', 'pose_stamped_to_transform',
    'transform_to_pose_stamped',
]
