import numpy as np
import pytest

from tlessbot_ros.conversions import (
    RosbagsFactory,
    camera_info_to_intrinsics,
    image_to_array,
    pointcloud2_to_xyz,
)
from tlessbot_ros.conversions.camera import camera_frame_messages
from tlessbot_ros.conversions.topics import CAMERA_TOPICS
from tlessbot_ros.core.common import d415_intrinsics


def test_frame_messages_are_consistent():
    intrinsics = d415_intrinsics(64, 48)
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    depth = rng.integers(300, 1200, (48, 64)).astype(np.uint16)
    depth[:10] = 0
    msgs = camera_frame_messages('side', rgb, depth, intrinsics, 123_456_789,
                                 factory=RosbagsFactory())
    assert set(msgs) == set(CAMERA_TOPICS)
    for msg in msgs.values():
        assert msg.header.frame_id == 'side_color_optical_frame'
        assert msg.header.stamp.nanosec == 123_456_789
    np.testing.assert_array_equal(image_to_array(msgs['color/image_raw']), rgb)
    np.testing.assert_array_equal(image_to_array(msgs['aligned_depth_to_color/image_raw']), depth)
    np.testing.assert_array_equal(
        camera_info_to_intrinsics(msgs['aligned_depth_to_color/camera_info']).K, intrinsics.K)
    xyz, colours = pointcloud2_to_xyz(msgs['depth/color/points'])
    assert len(xyz) == int((depth > 0).sum())
    np.testing.assert_allclose(np.sort(xyz[:, 2]), np.sort(depth[depth > 0] / 1000.0),
                               rtol=1e-6)
    sparse = camera_frame_messages('side', rgb, depth, intrinsics, 0, cloud_stride=4,
                                   factory=RosbagsFactory())
    assert len(pointcloud2_to_xyz(sparse['depth/color/points'])[0]) == \
        int((depth[::4, ::4] > 0).sum())


def test_size_mismatch_raises():
    with pytest.raises(ValueError, match='sizes must agree'):
        camera_frame_messages('top', np.zeros((4, 4, 3), np.uint8), np.zeros((4, 5), np.uint16),
                              d415_intrinsics(64, 48), 0, factory=RosbagsFactory())
