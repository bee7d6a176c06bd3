"""evaluate's count of false parts outside the scored camera (tools/support/unseen_parts.py):
poses the other camera found beside the scored image, which its false-positive figure
cannot hold."""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics, make_transform
from tlessbot_ros.io.bop import BopGroundTruth, BopImage
from tlessbot_ros.io.bop_results import BopEstimate
from tlessbot_ros.tools.support.eval_scoring import FrameOutput, score_frames, scoring_model
from tlessbot_ros.tools.support.report import markdown
from tlessbot_ros.tools.support.unseen_parts import outside_image, unscored_false_parts


def _cube(obj_id: int = 1, half: float = 0.02):
    corners = np.array([[x, y, z] for x in (-half, half) for y in (-half, half)
                        for z in (-half, half)])
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return scoring_model(obj_id, corners, faces, diameter_m=2 * half * np.sqrt(3))


def _frame():
    """A 100 px image at f = 100: a part in view at x = 0 and one beside it at x = 0.5 m
    (0.5 m away, it projects to u = 150); poses: the part in view, the part beside it
    (found by the other camera: no false part), a false one beside the image, a false one
    in view (the scored view's figures hold that one)."""
    intrinsics = CameraIntrinsics(100, 100, np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]]))

    def at(x: float, y: float = 0.0):
        return make_transform(np.eye(3), [x, y, 0.5])

    image = BopImage('test', 1, 0, None, None, intrinsics, None,
                     [BopGroundTruth(1, at(0.0), (40, 40, 20, 20), 1.0),
                      BopGroundTruth(1, at(0.5), None, 0.0)])
    poses = [BopEstimate(1, 0, 1, 1.0, at(x, y))
             for x, y in ((0.0, 0.0), (0.51, 0.0), (0.5, 0.3), (0.1, 0.1))]
    return image, poses


def test_outside_image_tells_where_a_point_projects():
    image, _ = _frame()
    assert not outside_image(image, [0.0, 0.0, 0.5])
    assert outside_image(image, [0.5, 0.0, 0.5])
    assert outside_image(image, [0.0, 0.0, -0.5])     # behind the camera


def test_only_poses_beside_the_image_and_near_no_part_count():
    image, poses = _frame()
    assert unscored_false_parts(image, poses, lambda obj_id: 0.035) == 1


def test_evaluate_reports_them_apart_from_its_false_positives():
    image, poses = _frame()
    report = score_frames([(image, FrameOutput(poses=poses))], {1: _cube()})
    assert report['detection']['unscored_false_parts_per_frame'] == 1.0
    assert report['detection']['false_pos_per_frame'] is None    # no boxes: unchanged
    assert 'false parts outside the scored camera per frame (' in markdown(report)
    assert markdown(report).split('false parts outside the scored camera')[1] \
        .splitlines()[0].endswith(' 1.000')
    # frames where the pose stage did not run: nothing to count
    skipped = score_frames([(image, FrameOutput(pose_ran=False))], {1: _cube()})
    assert skipped['detection']['unscored_false_parts_per_frame'] is None
