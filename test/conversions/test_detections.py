"""Detection3DArray, TFMessage and DetectedPart round trips (rclpy messages from the generated
packages, no rclpy.init())."""
import numpy as np
import pytest

from tlessbot_ros.conversions.detections import (
    PartPose,
    detection_array_to_parts,
    part_to_detected_part,
    parts_to_detection_array,
    tf_message_to_transforms,
    transforms_to_tf_message,
)
from tlessbot_ros.conversions.messages import RclpyFactory
from tlessbot_ros.core.common.geometry import make_transform, rotation_about_axis

pytest.importorskip('vision_msgs.msg', reason='make setup builds vision_msgs')


def random_pose(rng):
    axis = rng.normal(size=3)
    return make_transform(rotation_about_axis(axis / np.linalg.norm(axis), rng.uniform(0, 3)),
                          rng.uniform(-0.5, 0.5, 3))


def test_detection_array_round_trip():
    rng = np.random.default_rng(1)
    parts = [PartPose('obj_05', random_pose(rng), 'side_color_optical_frame', 0.8,
                      np.array([0.08, 0.05, 0.04]), np.array([0.001, -0.002, 0.003]), 'obj_05_2'),
             PartPose('obj_07', random_pose(rng), 'world', 0.6, np.array([0.03, 0.03, 0.02]))]
    msg = parts_to_detection_array(parts, frame_id='world', stamp_ns=12_345_678_901,
                                   factory=RclpyFactory())
    assert msg.header.frame_id == 'world' and msg.header.stamp.sec == 12
    assert [d.header.stamp.nanosec for d in msg.detections] == [345_678_901] * 2
    back, stamp_ns = detection_array_to_parts(msg)
    assert stamp_ns == 12_345_678_901
    for a, b in zip(parts, back):
        assert (a.part, a.frame_id, a.instance) == (b.part, b.frame_id, b.instance)
        assert b.score == pytest.approx(a.score)
        np.testing.assert_allclose(b.T, a.T, atol=1e-9)
        np.testing.assert_allclose(b.box_size_m, a.box_size_m)
        np.testing.assert_allclose(b.box_centre_m, a.box_centre_m, atol=1e-9)


def test_empty_frame_is_an_empty_array():
    msg = parts_to_detection_array([], frame_id='world', stamp_ns=5, factory=RclpyFactory())
    assert list(msg.detections) == [] and msg.header.stamp.nanosec == 5


def test_detection_without_hypothesis_is_refused():
    msg = parts_to_detection_array([PartPose('obj_05', np.eye(4), 'world')], frame_id='world',
                                   stamp_ns=0, factory=RclpyFactory())
    msg.detections[0].results = []
    with pytest.raises(ValueError, match='no hypothesis'):
        detection_array_to_parts(msg)


def test_tf_round_trip():
    rng = np.random.default_rng(2)
    items = [('world', 'top_color_optical_frame', random_pose(rng)),
             ('world', 'obj_05_1', random_pose(rng))]
    msg = transforms_to_tf_message(items, stamp_ns=7_000_000_001, factory=RclpyFactory())
    back = tf_message_to_transforms(msg)
    for (parent, child, T), (p2, c2, T2, stamp) in zip(items, back):
        assert (parent, child, stamp) == (p2, c2, 7_000_000_001)
        np.testing.assert_allclose(T2, T, atol=1e-9)


def test_detected_part():
    T = make_transform(np.eye(3), np.array([0.1, 0.2, 0.3]))
    msg = part_to_detected_part(PartPose('obj_05', T, 'world', 0.9, np.array([1, 2, 3.0]),
                                         instance='obj_05_1'), stamp_ns=3,
                                factory=RclpyFactory())
    assert (msg.part, msg.instance, msg.pose.header.frame_id) == ('obj_05', 'obj_05_1', 'world')
    assert msg.pose.pose.position.z == pytest.approx(0.3) and msg.box_size.z == 3.0
