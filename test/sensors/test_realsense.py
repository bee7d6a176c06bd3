"""The device-free driver path on real RealSense frames, and the real device (hardware)."""
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from tlessbot_ros.conversions import (
    RosbagsFactory,
    depth_image_to_metres,
    image_to_array,
    pointcloud2_to_xyz,
)
from tlessbot_ros.conversions.camera import camera_frame_messages
from tlessbot_ros.sensors.realsense import (
    RealSenseCamera,
    RealSenseParams,
    depth_to_mm,
    intrinsics_from_rs,
)


def test_depth_scale_conversion():
    raw = np.array([[0, 1000, 4000]], np.uint16)
    np.testing.assert_array_equal(depth_to_mm(raw, 0.001), raw)
    np.testing.assert_array_equal(depth_to_mm(raw, 0.0001), [[0, 100, 400]])
    with pytest.raises(ValueError):
        depth_to_mm(raw, 0.0)


def test_intrinsics_from_rs_struct():
    rs_intr = SimpleNamespace(width=640, height=480, fx=605.1, fy=604.8, ppx=325.5, ppy=244.9,
                              coeffs=[0.0] * 5, model='distortion.inverse_brown_conrady')
    intrinsics = intrinsics_from_rs(rs_intr)
    assert (intrinsics.fx, intrinsics.cy, intrinsics.distortion_model) == (605.1, 244.9,
                                                                          'plumb_bob')


def test_real_d435_frame_to_messages(shared_data):
    folder = shared_data / 'visp_realsense_tutorial_data/computer-vision/d435_align_depth'
    bgr = cv2.imread(str(folder / 'color_image_0000.jpg'))
    raw = (folder / 'depth_image_0000.bin').read_bytes()
    height, width = np.frombuffer(raw[:8], '<u4')
    depth_raw = np.frombuffer(raw[8:], '<u2').reshape(int(height), int(width))
    rs_intr = SimpleNamespace(width=640, height=480, fx=605.146728515625, fy=604.79150390625,
                              ppx=325.53253173828125, ppy=244.95083618164062, coeffs=[0.0] * 5)
    intrinsics = intrinsics_from_rs(rs_intr)
    rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    msgs = camera_frame_messages('top', rgb, depth_to_mm(depth_raw, 0.001), intrinsics,
                                 1_700_000_000_000_000_000, factory=RosbagsFactory())
    np.testing.assert_array_equal(image_to_array(msgs['color/image_raw']), rgb)
    depth_m = depth_image_to_metres(msgs['aligned_depth_to_color/image_raw'])
    valid = depth_raw > 0
    np.testing.assert_allclose(depth_m[valid], depth_raw[valid] / 1000.0, rtol=1e-6)
    xyz, colours = pointcloud2_to_xyz(msgs['depth/color/points'])
    assert len(xyz) == int(valid.sum())
    rows, cols = np.nonzero(valid)
    np.testing.assert_array_equal(colours, rgb[rows, cols])
    assert 0.2 < float(np.median(xyz[:, 2])) < 3.0  # a desk scene seen by a D435


@pytest.mark.hardware
def test_real_device_streams_aligned_frames():
    camera = RealSenseCamera(RealSenseParams(width=640, height=480, fps=30))
    camera.open()
    try:
        frame = camera.read()
    finally:
        camera.close()
    assert frame.rgb.shape == (480, 640, 3) and frame.depth_mm.shape == (480, 640)
    assert (frame.depth_mm > 0).mean() > 0.3
    assert 550 < frame.intrinsics.fx < 700
