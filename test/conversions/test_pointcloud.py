import numpy as np
import pytest

from tlessbot_ros.conversions import (
    RclpyFactory,
    RosbagsFactory,
    array_to_image,
    depth_image_to_pointcloud2,
    intrinsics_to_camera_info,
    pointcloud2_to_xyz,
    xyz_to_pointcloud2,
)
from tlessbot_ros.core.common import CameraIntrinsics

FACTORIES = [pytest.param(RosbagsFactory(), id='rosbags'),
             pytest.param(RclpyFactory(), id='rclpy', marks=pytest.mark.ros)]


@pytest.mark.parametrize('factory', FACTORIES)
@pytest.mark.parametrize('with_rgb', [False, True])
def test_round_trip(factory, with_rgb):
    rng = np.random.default_rng(1)
    xyz = rng.normal(size=(100, 3)).astype(np.float32)
    rgb = rng.integers(0, 256, (100, 3), dtype=np.uint8) if with_rgb else None
    msg = xyz_to_pointcloud2(xyz, rgb, frame_id='top_color_optical_frame', stamp_ns=7,
                             factory=factory)
    assert [f.name for f in msg.fields] == (['x', 'y', 'z', 'rgb'] if with_rgb else list('xyz'))
    assert msg.point_step == (20 if with_rgb else 16)
    xyz_back, rgb_back = pointcloud2_to_xyz(msg)
    np.testing.assert_array_equal(xyz_back, xyz)
    if with_rgb:
        np.testing.assert_array_equal(rgb_back, rgb)
    else:
        assert rgb_back is None


def test_realsense_rgb_byte_order():
    # realsense-ros writes B, G, R at offset 16: pure red is bytes (0, 0, 255, 0).
    msg = xyz_to_pointcloud2(np.zeros((1, 3), np.float32), np.array([[255, 0, 0]], np.uint8),
                             factory=RosbagsFactory())
    assert list(np.asarray(msg.data)[16:20]) == [0, 0, 255, 0]


def _custom_cloud(big_endian: bool):
    """An organised 2x3 cloud with float64 z first, a uint16 ring, NaN points and padding."""
    factory = RosbagsFactory()
    z = np.array([1.0, np.nan, 3.0, 4.0, 5.0, 6.0])
    x = np.arange(6, dtype=np.float32)
    y = -np.arange(6, dtype=np.float32)
    order = '>' if big_endian else '<'
    dtype = np.dtype([('z', order + 'f8'), ('ring', order + 'u2'), ('pad', 'V2'),
                      ('x', order + 'f4'), ('y', order + 'f4'), ('tail', 'V4')])
    records = np.zeros(6, dtype)
    records['z'], records['x'], records['y'], records['ring'] = z, x, y, 7
    row = records.reshape(2, 3).view(np.uint8).reshape(2, -1)
    padded = np.zeros((2, row.shape[1] + 8), np.uint8)
    padded[:, :row.shape[1]] = row
    fields = [factory.new('sensor_msgs/msg/PointField', name=n, offset=o, datatype=d, count=1)
              for n, o, d in (('z', 0, 8), ('ring', 8, 4), ('x', 12, 7), ('y', 16, 7))]
    return factory.new('sensor_msgs/msg/PointCloud2', height=2, width=3, fields=fields,
                       is_bigendian=big_endian, point_step=dtype.itemsize,
                       row_step=padded.shape[1], data=padded.ravel(), is_dense=False)


@pytest.mark.parametrize('big_endian', [False, True])
def test_arbitrary_layout_by_name_and_offset(big_endian):
    xyz, rgb = pointcloud2_to_xyz(_custom_cloud(big_endian))
    assert rgb is None
    np.testing.assert_array_equal(xyz, [[0, 0, 1], [2, -2, 3], [3, -3, 4], [4, -4, 5],
                                        [5, -5, 6]])


def test_missing_field_and_bad_length_raise():
    msg = _custom_cloud(False)
    msg.fields = [f for f in msg.fields if f.name != 'y']
    with pytest.raises(ValueError, match='lacks field'):
        pointcloud2_to_xyz(msg)
    msg = _custom_cloud(False)
    msg.data = msg.data[:-3]
    with pytest.raises(ValueError, match='row_step'):
        pointcloud2_to_xyz(msg)


def test_empty_cloud_is_valid():
    xyz, _ = pointcloud2_to_xyz(xyz_to_pointcloud2(np.zeros((0, 3), np.float32),
                                                   factory=RosbagsFactory()))
    assert xyz.shape == (0, 3)


def test_depth_image_to_cloud_uses_header_and_skips_invalid():
    factory = RosbagsFactory()
    intrinsics = CameraIntrinsics(width=4, height=3, K=np.array([[2.0, 0, 1.5], [0, 2.0, 1.0],
                                                                 [0, 0, 1]]))
    depth_mm = np.full((3, 4), 1000, np.uint16)
    depth_mm[0, 0] = 0
    depth = array_to_image(depth_mm, '16UC1', frame_id='side_color_optical_frame',
                           stamp_ns=99, factory=factory)
    info = intrinsics_to_camera_info(intrinsics, factory=factory)
    colour = np.zeros((3, 4, 3), np.uint8)
    colour[2, 3] = (10, 20, 30)
    cloud = depth_image_to_pointcloud2(depth, info, colour, factory=factory)
    assert cloud.header.frame_id == 'side_color_optical_frame'
    assert cloud.header.stamp.nanosec == 99
    xyz, rgb = pointcloud2_to_xyz(cloud)
    assert len(xyz) == 11
    np.testing.assert_allclose(xyz[-1], [(3 - 1.5) / 2.0, (2 - 1.0) / 2.0, 1.0])
    np.testing.assert_array_equal(rgb[-1], [10, 20, 30])
