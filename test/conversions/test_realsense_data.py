"""Real D435 aligned depth from ViSP's tutorial data through Image -> array -> point cloud."""
import numpy as np
import pytest
from realsense_frames import read_visp_camera_xml, read_visp_depth_bin

from tlessbot_ros.conversions import (
    RosbagsFactory,
    array_to_image,
    depth_image_to_metres,
    depth_image_to_pointcloud2,
    image_to_array,
    intrinsics_to_camera_info,
    pointcloud2_to_xyz,
)
from tlessbot_ros.core.common import project_points


@pytest.fixture(scope='module')
def d435(shared_data):
    folder = shared_data / 'visp_realsense_tutorial_data/computer-vision/d435_align_depth'
    return read_visp_depth_bin(folder / 'depth_image_0000.bin'), \
        read_visp_camera_xml(folder / 'camera.xml')


def test_aligned_depth_to_cloud_and_back(d435):
    depth_mm, intrinsics = d435
    assert depth_mm.shape == (480, 640)
    assert intrinsics.fx == pytest.approx(605.1467)
    factory = RosbagsFactory()
    msg = array_to_image(depth_mm, '16UC1', frame_id='camera_color_optical_frame',
                         stamp_ns=1, factory=factory)
    np.testing.assert_array_equal(image_to_array(msg), depth_mm)
    cloud = depth_image_to_pointcloud2(
        msg, intrinsics_to_camera_info(intrinsics, factory=factory), factory=factory)
    xyz, _ = pointcloud2_to_xyz(cloud)

    valid = depth_mm > 0
    assert len(xyz) == int(valid.sum())
    assert 0.5 * depth_mm.size < len(xyz) < depth_mm.size  # a real frame: most pixels valid
    assert np.median(xyz[:, 2]) == pytest.approx(np.median(depth_mm[valid]) / 1000.0, abs=1e-6)
    # Reprojection gives back the pixel grid, in row-major order of the valid pixels.
    rows, cols = np.nonzero(valid)
    uv = project_points(xyz, intrinsics.K)
    np.testing.assert_allclose(uv[:, 0], cols, atol=1e-3)
    np.testing.assert_allclose(uv[:, 1], rows, atol=1e-3)
    # Metric depth agrees with the mm image.
    metres = depth_image_to_metres(msg)
    np.testing.assert_allclose(metres[valid], depth_mm[valid] / 1000.0, rtol=1e-6)
