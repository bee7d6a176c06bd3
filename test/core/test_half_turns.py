"""Half turns a part's depth may not rule out: an L bracket whose legs differ by a quarter fits
its depth nearly as well turned about the diagonal between them (no turn the near-symmetric
listing tries), and the aligned height and colour votes turn the fit back."""
from __future__ import annotations

import numpy as np
import pytest
from side_scene import SIDE, side_scene

from tlessbot_ros.core.common import (
    depth_to_points,
    make_transform,
    plane_of_frame,
    rotation_angle_deg,
)
from tlessbot_ros.core.pose import PoseParams, Refiner, TurnParams, build_database, near_turns
from tlessbot_ros.core.pose.flat import FlatCheck, FlatParams, ViewEvidence
from tlessbot_ros.core.pose.half_turns import choose_half_turn, self_half_turns
from tlessbot_ros.tools.support import part_generator as gen

DIAGONAL = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)   # between the bracket's legs (x, z)


@pytest.fixture(scope='module')
def bracket():
    """The generator's short bracket (legs 40 and 30 mm, 25 wide, 5 thick): (vertices m,
    faces), its templates resting on its long leg, their database."""
    sdf, (low, high) = gen.part_shapes()['bracket_short']
    v, f = gen.mesh_part(sdf, low, high, spacing_mm=0.7)
    v = v / 1000.0
    lift = make_transform(np.eye(3), [0.0, 0.0, -float(v[:, 2].min())])
    db = build_database([(1, v, f, [(lift, 1.0)], None)], intrinsics=SIDE.intrinsics,
                        T_world_camera=SIDE.T_world_camera)
    return v, f, db[1], db


def _axis(S: np.ndarray) -> np.ndarray:
    w, V = np.linalg.eig(S[:3, :3])
    return np.real(V[:, np.argmin(np.abs(w - 1))])


def test_the_diagonal_half_turn_is_listed_where_the_turn_listing_has_none(bracket):
    _, _, obj, _ = bracket
    turns = self_half_turns(obj)
    assert len(turns)
    assert all(abs(rotation_angle_deg(S[:3, :3], np.eye(3)) - 180.0) < 1e-6 for S in turns)
    assert max(abs(_axis(S) @ DIAGONAL) for S in turns) > 0.99
    # the near-symmetric listing (5° steps about the model and principal axes) has no turn
    # about that diagonal
    assert all(abs(_axis(S) @ DIAGONAL) < 0.99 for S in near_turns(obj))


def test_an_exact_symmetry_is_no_candidate():
    """A plain box: its half turns about its axes look the same; none is listed."""
    sdf = gen._box((0, 0, 10), (20, 15, 10))
    v, f = gen.mesh_part(sdf, np.array([-21.0, -16, -1]), np.array([21.0, 16, 21]),
                         spacing_mm=0.8)
    v = v / 1000.0
    db = build_database([(1, v, f, [(make_transform(np.eye(3), [0, 0, 0]), 1.0)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    for S in self_half_turns(db[1]):
        assert min(abs(_axis(S) @ e) for e in np.eye(3)) < 0.99   # no box axis


def _views_and_cloud(v, f, T_world_object):
    rgb, depth, mask = side_scene(v, f, T_world_object, noise_m=0.0005, shaded=True)
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask)
    view = ViewEvidence(rgb, mask, SIDE.intrinsics, np.eye(4), depth,
                        plane_of_frame(SIDE.T_world_camera), np.zeros_like(mask))
    return [view], points


def test_a_fit_stuck_on_the_diagonal_half_turn_is_turned_back(bracket):
    v, f, obj, _ = bracket
    lift = -float(v[:, 2].min())
    T_world_object = make_transform(np.eye(3), [0.005, -0.01, lift]) @ make_transform(
        np.eye(3), [-0.02, 0.0, 0.0])
    views, points = _views_and_cloud(v, f, T_world_object)
    T_true = np.linalg.inv(SIDE.T_world_camera) @ T_world_object
    refiner = Refiner(PoseParams())
    check = FlatCheck(refiner, FlatParams())
    scene = check.prepared_cloud(obj, points)
    S = min(self_half_turns(obj), key=lambda S: -abs(_axis(S) @ DIAGONAL))
    # the fit's ICP from the diagonal turn ends near it: a local minimum of the depth
    T_stuck = refiner.icp_batch(scene, obj, (T_true @ S)[None], iterations=30)[0]
    assert rotation_angle_deg(T_stuck[:3, :3], T_true[:3, :3]) > 150.0
    turned, info = choose_half_turn(check, obj, T_stuck, scene, views, TurnParams())
    assert info['half_winner'] > 0 and info['half_decided'] == 1.0, info
    assert rotation_angle_deg(turned[:3, :3], T_true[:3, :3]) < 5.0, info
    kept, info = choose_half_turn(check, obj, T_true, scene, views, TurnParams())
    assert info['half_winner'] == 0.0 and np.array_equal(kept, T_true), info


def test_no_candidates_without_a_table_plane(bracket):
    v, f, obj, _ = bracket
    T = np.linalg.inv(SIDE.T_world_camera) @ make_transform(np.eye(3), [0.0, 0.0, 0.0])
    view = ViewEvidence(None, np.zeros((480, 640), bool), SIDE.intrinsics, np.eye(4))
    check = FlatCheck(Refiner(PoseParams()), FlatParams())
    kept, info = choose_half_turn(check, obj, T, np.zeros((50, 3)), [view], TurnParams())
    assert np.array_equal(kept, T) and info['half_turns'] == 0.0


def test_half_turn_params_reject_bad_values():
    with pytest.raises(ValueError, match='half_min_share'):
        TurnParams(half_min_share=1.5)
    with pytest.raises(ValueError, match='half_icp_iterations'):
        TurnParams(half_icp_iterations=0)


def test_the_pipeline_turns_a_stuck_fit_back(bracket):
    """In the composed pipeline (the checks after a fit): a bracket fitted at the diagonal
    half turn comes out at the true pose, the stuck fit its second."""
    from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
    from tlessbot_ros.core.pose.candidates import PoseCandidate

    v, f, obj, database = bracket
    lift = -float(v[:, 2].min())
    T_world_object = make_transform(np.eye(3), [-0.015, -0.01, lift])
    rgb, depth, mask = side_scene(v, f, T_world_object, noise_m=0.0005, shaded=True)
    T_true = np.linalg.inv(SIDE.T_world_camera) @ T_world_object
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask)
    refiner = Refiner(PoseParams())
    S = min(self_half_turns(obj), key=lambda S: -abs(_axis(S) @ DIAGONAL))
    T_stuck = refiner.icp_batch(points, obj, (T_true @ S)[None], iterations=30)[0]

    class StuckFitter:
        def fit_all(self, jobs, fit_here, on_done):
            for job in jobs:
                job.detection.pose = PoseCandidate(T_stuck, 0.9, 0.001, 1.0, 'table', -1, 0)
                on_done(job)

    pipeline = PerceptionPipeline(templates=database)
    views = {'side': ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}
    [detection] = pipeline.estimate_poses(views, {'side': mask.astype(np.uint16)}, {1: 1},
                                          box_mode=True, fitter=StuckFitter())
    assert rotation_angle_deg(detection.pose.T_camera_object[:3, :3], T_true[:3, :3]) < 5.0
    assert np.array_equal(detection.second.T_camera_object, T_stuck)


def test_the_best_turn_need_only_beat_the_given_rivals(monkeypatch):
    """Two turns either side of a disc's true yaw split their duel (12 against 10 pixels): the
    winner beats every pose clearly but its neighbour. Against every pose it is undecided
    (the fitted pose stays); with the fitted pose as its only rival it is taken."""
    from tlessbot_ros.core.pose import flat_align

    votes = np.array([[0, 2, 3, 10],
                      [40, 0, 12, 40],
                      [42, 10, 0, 40],
                      [10, 5, 5, 0]])
    monkeypatch.setattr(flat_align, 'view_votes', lambda *args, **kwargs: votes)
    check = FlatCheck(Refiner(PoseParams()), FlatParams())
    obj = type('Obj', (), {'model_points': np.zeros((3, 3), np.float32)})()
    poses = [np.eye(4)] * 4
    info: dict[str, float] = {}
    assert check.aligned_winner(obj, [None] * 4, poses, [], info) == 0
    assert info['align_winner'] == 1.0 and info['align_decided'] == 0.0
    assert check.aligned_winner(obj, [None] * 4, poses, [], info, rivals=[0]) == 1
    assert info['align_decided'] == 1.0
