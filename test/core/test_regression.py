"""Matching a run's poses with approved ones (core.regression): no ROS, no graph."""
import numpy as np
import pytest

from tlessbot_ros.core.common import Symmetries, make_transform, rotation_about_axis
from tlessbot_ros.core.regression import (
    ADDED,
    FRAME_CHANGED,
    MATCH,
    MISSING,
    MOVED,
    RENAMED,
    PartPose,
    Tolerance,
    check_frames,
    match_frame,
)

FRAME = 'side_color_optical_frame'


def _part(name, xyz, yaw_deg=0.0, frame=FRAME, score=0.9):
    R = rotation_about_axis(np.array([0.0, 0.0, 1.0]), np.radians(yaw_deg))
    return PartPose(name, make_transform(R, np.array(xyz, float)), frame, score)


def test_same_parts_match_and_small_moves_stay_within_tolerance():
    expected = [_part('obj_05', [0.1, 0.0, 0.6], 10), _part('obj_05', [-0.1, 0.0, 0.6], 40)]
    actual = [_part('obj_05', [-0.1, 0.002, 0.6], 41.0), _part('obj_05', [0.1, 0.0, 0.6], 10)]
    checks = match_frame(7, expected, actual, {})
    assert [c.status for c in checks] == [MATCH, MATCH]
    assert checks[1].actual is actual[0]      # nearest pose, not list order
    assert checks[1].error.translation_m == pytest.approx(0.002)
    assert checks[1].error.rotation_deg == pytest.approx(1.0)


def test_moves_beyond_either_tolerance_fail_and_the_tolerances_are_settable():
    expected = [_part('obj_05', [0.1, 0.0, 0.6]), _part('obj_06', [0.0, 0.1, 0.6])]
    actual = [_part('obj_05', [0.106, 0.0, 0.6]), _part('obj_06', [0.0, 0.1, 0.6], 3.0)]
    assert [c.status for c in match_frame(1, expected, actual, {})] == [MOVED, MOVED]
    loose = Tolerance(position_m=0.01, angle_deg=5.0)
    assert [c.status for c in match_frame(1, expected, actual, {}, loose)] == [MATCH, MATCH]
    with pytest.raises(ValueError, match='positive'):
        Tolerance(position_m=0.0)


def test_a_turn_onto_a_symmetric_pose_is_no_move():
    # obj_01-like: 2-fold about z (a half turn gives the same surface)
    half_turn = make_transform(rotation_about_axis(np.array([0.0, 0.0, 1.0]), np.pi), np.zeros(3))
    symmetries = {'obj_01': Symmetries(discrete=[np.eye(4), half_turn])}
    expected = [_part('obj_01', [0.0, 0.0, 0.6], 20)]
    actual = [_part('obj_01', [0.0, 0.0, 0.6], 200)]
    assert match_frame(1, expected, actual, symmetries)[0].status == MATCH
    assert match_frame(1, expected, actual, {})[0].status == MOVED


def test_missing_added_renamed_and_frame_changed():
    expected = [_part('obj_05', [0.1, 0.0, 0.6]), _part('obj_06', [0.0, 0.1, 0.6]),
                _part('obj_07', [-0.1, 0.0, 0.6]), _part('obj_08', [0.0, -0.1, 0.6])]
    actual = [_part('obj_09', [0.0, 0.101, 0.6]),            # obj_06 under another name
              _part('obj_07', [-0.1, 0.0, 0.6], frame='world'),
              _part('obj_08', [0.0, -0.1, 0.6]),
              _part('obj_11', [0.2, 0.2, 0.6])]              # nothing was approved there
    checks = match_frame(3, expected, actual, {})
    assert [(c.name, c.status) for c in checks] == [
        ('obj_05', MISSING), ('obj_06', RENAMED), ('obj_07', FRAME_CHANGED), ('obj_08', MATCH),
        ('obj_11', ADDED)]
    assert checks[1].describe() == 'name changed: obj_06 -> obj_09'
    assert 'side_color_optical_frame -> world' in checks[2].describe()
    assert all(c.stamp_ns == 3 for c in checks)


def test_check_frames_covers_frames_of_either_run_in_stamp_order():
    expected = {20: [_part('obj_05', [0.1, 0.0, 0.6])], 10: []}
    actual = {10: [_part('obj_05', [0.1, 0.0, 0.6])], 30: []}
    checks = check_frames(expected, actual, {})
    assert [(c.stamp_ns, c.status) for c in checks] == [(10, ADDED), (20, MISSING)]
    assert check_frames({1: []}, {1: []}, {}) == []
