import numpy as np

from tlessbot_ros.core.common import Symmetries, make_transform, rotation_about_axis
from tlessbot_ros.io.ground_truth import GroundTruthInstance
from tlessbot_ros.tools.support.bag_scoring import Estimate, compare_pose_sets, score_frame

SIDE = 'side_color_optical_frame'


def _part(obj_id, instance, x, visib=0.8):
    T = make_transform(np.eye(3), [x, 0.0, 0.6])
    return GroundTruthInstance(obj_id, instance, {SIDE: T}, {'side': visib, 'top': 0.1})


def test_matching_counts_correct_wrong_missed_and_false_positives():
    truth = [_part(5, 0, 0.0), _part(5, 1, 0.1), _part(21, 2, -0.1), _part(7, 3, 0.2, 0.1)]
    tilted = make_transform(rotation_about_axis([1, 0, 0], np.radians(10)), [0.1, 0, 0.6])
    estimates = [
        Estimate(0, 5, make_transform(np.eye(3), [0.101, 0.0, 0.6]), SIDE),  # part 1, 1 mm
        Estimate(0, 5, tilted, SIDE),                     # second obj 5: part 0, 10 cm + 10 deg
        Estimate(0, 30, make_transform(np.eye(3), [0.0, 0.0, 0.6]), SIDE),  # wrong class
        Estimate(0, 7, make_transform(np.eye(3), [0.2, 0.0, 0.6]), SIDE),   # invisible part
    ]
    matches, false_positives = score_frame(truth, estimates, {})
    assert [m.truth.instance for m in matches] == [0, 1, 2]  # part 3 is < 30 % visible
    assert [m.correct for m in matches] == [False, True, False]
    assert matches[2].estimate is None  # obj 21 missed
    assert abs(matches[1].error.translation_m - 0.001) < 1e-9
    assert [e.obj_id for e in false_positives] == [30]


def test_symmetric_part_is_correct_when_turned_about_its_axis():
    axis_sym = Symmetries(continuous=((np.array([0.0, 0.0, 1.0]), np.zeros(3)),))
    truth = [_part(2, 0, 0.0)]
    turned = make_transform(rotation_about_axis([0, 0, 1], np.radians(70)), [0, 0, 0.6])
    estimate = [Estimate(0, 2, turned, SIDE)]
    assert not score_frame(truth, estimate, {})[0][0].correct
    assert score_frame(truth, estimate, {2: axis_sym})[0][0].correct


def test_frame_duplicates_compare_poses_across_camera_frames():
    from tlessbot_ros.core.common import default_rig
    from tlessbot_ros.tools.support.bag_scoring import Estimate, frame_duplicates

    rig = default_rig()
    T_world_object = np.eye(4)
    T_world_object[:3, 3] = [0.05, 0.02, 0.01]
    side, top = rig['side'], rig['top']
    seen_from_side = Estimate(1, 8, side.T_camera_world @ T_world_object, side.optical_frame)
    seen_from_top = Estimate(1, 22, top.T_camera_world @ T_world_object, top.optical_frame)
    elsewhere = Estimate(1, 5, np.eye(4), 'world')
    assert frame_duplicates([seen_from_side, elsewhere], rig) == 0
    assert frame_duplicates([seen_from_side, seen_from_top, elsewhere], rig) == 1


def test_pose_sets_pair_by_frame_class_and_frame_id_closest_first():
    def at(x, stamp=0, obj=5):
        return Estimate(stamp, obj, make_transform(np.eye(3), [x, 0, 0.6]), SIDE)

    reference = [at(0.0), at(0.1), at(0.3, stamp=1), at(0.0, obj=7)]
    # two obj 5 poses of frame 0 in the other order (one 2 mm off), frame 1's 6 cm off,
    # obj 7 missing, an obj 9 the reference does not have
    other = [at(0.102), at(0.0), at(0.36, stamp=1), at(0.0, obj=9)]
    comparison = compare_pose_sets(reference, other, {})
    assert sorted(round(e.translation_m, 6) for e in comparison.errors) == [0.0, 0.002, 0.06]
    assert comparison.within_5cm_5deg == 2
    assert (comparison.unpaired_reference, comparison.unpaired_other) == (1, 1)
