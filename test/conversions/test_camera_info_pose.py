import numpy as np
import pytest

from tlessbot_ros.conversions import (
    RclpyFactory,
    RosbagsFactory,
    camera_info_to_intrinsics,
    intrinsics_to_camera_info,
    pose_stamped_to_transform,
    transform_to_pose_stamped,
)
from tlessbot_ros.core.common import (
    CameraIntrinsics,
    RegionOfInterest,
    make_transform,
    rotation_about_axis,
)

FACTORIES = [pytest.param(RosbagsFactory(), id='rosbags'),
             pytest.param(RclpyFactory(), id='rclpy', marks=pytest.mark.ros)]


@pytest.mark.parametrize('factory', FACTORIES)
def test_camera_info_round_trip(factory):
    intrinsics = CameraIntrinsics(
        width=640, height=480, K=np.array([[615.2, 0, 321.5], [0, 614.8, 240.25], [0, 0, 1]]),
        D=np.array([0.1, -0.2, 0.001, 0.002, 0.05]),
        roi=RegionOfInterest(10, 20, 300, 200, True))
    msg = intrinsics_to_camera_info(intrinsics, frame_id='side_color_optical_frame',
                                    stamp_ns=42, factory=factory)
    back = camera_info_to_intrinsics(msg)
    np.testing.assert_array_equal(back.K, intrinsics.K)
    np.testing.assert_array_equal(back.D, intrinsics.D)
    assert (back.width, back.height, back.roi) == (640, 480, intrinsics.roi)
    np.testing.assert_array_equal(np.asarray(msg.p).reshape(3, 4)[:, :3], intrinsics.K)


def test_unset_camera_info_is_rejected():
    msg = RosbagsFactory().new('sensor_msgs/msg/CameraInfo')
    with pytest.raises(ValueError, match='zero image size'):
        camera_info_to_intrinsics(msg)
    msg.width, msg.height = 640, 480
    with pytest.raises(ValueError, match='focal'):
        camera_info_to_intrinsics(msg)


@pytest.mark.parametrize('factory', FACTORIES)
def test_pose_round_trip(factory):
    for seed in range(20):
        rng = np.random.default_rng(seed)
        R = rotation_about_axis(rng.normal(size=3), rng.uniform(-np.pi, np.pi))
        T = make_transform(R, rng.normal(size=3))
        msg = transform_to_pose_stamped(T, frame_id='world', stamp_ns=5_000_000_001,
                                        factory=factory)
        back, frame_id, stamp_ns = pose_stamped_to_transform(msg)
        np.testing.assert_allclose(back, T, atol=1e-12)
        assert (frame_id, stamp_ns) == ('world', 5_000_000_001)


def test_bad_pose_is_rejected():
    msg = transform_to_pose_stamped(np.eye(4), frame_id='a', stamp_ns=0,
                                    factory=RosbagsFactory())
    msg.pose.orientation.w = 0.0
    with pytest.raises(ValueError, match='zero quaternion'):
        pose_stamped_to_transform(msg)
    msg.pose.position.x = float('nan')
    with pytest.raises(ValueError, match='non-finite'):
        pose_stamped_to_transform(msg)
