"""BOP pose error measures on hand-made cases with known answers."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import CameraIntrinsics, make_transform, rotation_about_axis
from tlessbot_ros.core.metrics import (
    BOP19_THRESHOLDS,
    ModelDepthRenderer,
    Symmetries,
    add,
    adds,
    average_recall,
    box_iou,
    is_correct_cm_deg,
    mspd,
    mssd,
    pose_error,
    recall,
    vsd,
)


def _box(size):
    sx, sy, sz = (s / 2 for s in size)
    v = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)], float)
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def _pose(axis=(0, 0, 1), deg=0.0, t=(0.0, 0.0, 0.5)):
    return make_transform(rotation_about_axis(np.asarray(axis, float), np.radians(deg)), t)


FLIP_Z = Symmetries(discrete=(_pose((0, 0, 1), 180, (0, 0, 0)),))
REVOLVED_Z = Symmetries(continuous=(((0, 0, 1), (0, 0, 0)),))
T_GT = _pose((1, 2, 3), 40, (0.02, -0.01, 0.6))


def test_pose_error_no_symmetry_is_the_plain_angle_and_distance():
    T_est = T_GT @ _pose((0, 0, 1), 30, (0, 0, 0))
    T_est[:3, 3] += [0.03, 0.04, 0.0]
    e = pose_error(T_est, T_GT)
    assert e.rotation_deg == pytest.approx(30.0)
    assert e.translation_m == pytest.approx(0.05)


@pytest.mark.parametrize('deg', [180.0, 170.0])
def test_discrete_flip_is_forgiven(deg):
    T_est = T_GT @ _pose((0, 0, 1), deg, (0, 0, 0))
    assert pose_error(T_est, T_GT, FLIP_Z).rotation_deg == pytest.approx(180.0 - deg, abs=1e-6)
    assert pose_error(T_est, T_GT).rotation_deg == pytest.approx(deg, abs=1e-6)


def test_continuous_axis_is_exact_and_only_about_its_axis():
    T_est = T_GT @ _pose((0, 0, 1), 73.0, (0, 0, 0))
    assert pose_error(T_est, T_GT, REVOLVED_Z).rotation_deg == pytest.approx(0.0, abs=1e-5)
    tilted = T_GT @ _pose((0, 0, 1), 73.0, (0, 0, 0)) @ _pose((1, 0, 0), 4.0, (0, 0, 0))
    assert pose_error(tilted, T_GT, REVOLVED_Z).rotation_deg == pytest.approx(4.0, abs=1e-5)
    # and it agrees with brute force over a fine discretisation
    brute = min(np.degrees(np.arccos(np.clip((np.trace(tilted[:3, :3].T @ (T_GT @ S)[:3, :3])
                                               - 1) / 2, -1, 1)))
                for S in REVOLVED_Z.transforms(step_rad=np.radians(0.1)))
    assert pose_error(tilted, T_GT, REVOLVED_Z).rotation_deg == pytest.approx(brute, abs=0.05)


def test_continuous_axis_with_offset_moves_the_translation():
    offset = np.array([0.01, 0.0, 0.0])
    s = Symmetries(continuous=(((0, 0, 1), offset),))
    R = rotation_about_axis(np.array([0, 0, 1.0]), np.pi)
    S = make_transform(R, offset - R @ offset)
    e = pose_error(T_GT @ S, T_GT, s)
    assert e.rotation_deg == pytest.approx(0.0, abs=1e-5)
    assert e.translation_m == pytest.approx(0.0, abs=1e-9)


def test_cm_deg_acceptance():
    T_est = T_GT @ _pose((0, 1, 0), 4.0, (0, 0, 0))
    T_est[:3, 3] += [0.0, 0.0, 0.02]
    e = pose_error(T_est, T_GT)
    assert is_correct_cm_deg(e)
    assert not is_correct_cm_deg(e, translation_m=0.01)
    assert not is_correct_cm_deg(pose_error(T_GT @ _pose((0, 1, 0), 6.0, (0, 0, 0)), T_GT))


def test_add_of_a_pure_translation_is_its_length():
    points = np.random.default_rng(0).normal(size=(500, 3)) * 0.03
    T_est = T_GT.copy()
    T_est[:3, 3] += [0.003, 0.004, 0.0]
    assert add(T_est, T_GT, points) == pytest.approx(0.005)
    assert adds(T_est, T_GT, points) <= 0.005 + 1e-12
    assert mssd(T_est, T_GT, points) == pytest.approx(0.005)


def test_adds_forgives_a_symmetry_add_does_not():
    v, f = _box((0.1, 0.06, 0.04))
    from tlessbot_ros.core.common import sample_surface
    points, _ = sample_surface(v, f, 3000, seed=0, scheme='sqrt')
    T_est = T_GT @ _pose((0, 0, 1), 180, (0, 0, 0))
    assert adds(T_est, T_GT, points) < 0.002
    assert add(T_est, T_GT, points) > 0.02
    assert mssd(T_est, T_GT, points, FLIP_Z) == pytest.approx(0.0, abs=1e-9)
    assert mssd(T_est, T_GT, points) > 0.05


def test_mspd_of_a_lateral_shift_is_the_pixel_shift():
    K = np.array([[500.0, 0, 320], [0, 500, 240], [0, 0, 1]])
    points = np.random.default_rng(1).normal(size=(200, 3)) * 0.02
    points[:, 2] = 0.0  # all at the same depth, so the shift is the same everywhere
    T_gt = _pose(t=(0.0, 0.0, 0.5))
    T_est = _pose(t=(0.001, 0.0, 0.5))  # 1 mm at 0.5 m = 1 px at f = 500
    assert mspd(T_est, T_gt, points, K) == pytest.approx(1.0, abs=1e-6)
    assert mspd(T_gt @ _pose((0, 0, 1), 180, (0, 0, 0)), T_gt, points, K, FLIP_Z) \
        == pytest.approx(0.0, abs=1e-6)


@pytest.fixture(scope='module')
def box_scene():
    v, f = _box((0.08, 0.06, 0.04))
    renderer = ModelDepthRenderer(v, f)
    intr = CameraIntrinsics.from_fov(160, 120, 60.0)
    T_gt = _pose((1, 1, 0), 30, (0.0, 0.0, 0.4))
    depth = np.zeros((120, 160), np.float32)
    window = renderer.box(intr, T_gt)
    x0, y0, x1, y1 = window
    depth[y0:y1, x0:x1] = renderer.depth(intr, T_gt, window)
    depth[depth == 0] = 0.6  # a wall behind the object
    return renderer, intr, T_gt, depth


def test_vsd_ground_truth_is_zero_far_pose_is_one(box_scene):
    renderer, intr, T_gt, depth = box_scene
    assert vsd(T_gt, T_gt, depth, intr, renderer)[0] == pytest.approx(0.0)
    far = _pose(t=(0.3, 0.2, 0.4))  # projects elsewhere: no overlap at all
    assert vsd(far, T_gt, depth, intr, renderer)[0] == pytest.approx(1.0)
    assert vsd(far, T_gt, depth, intr, renderer, visib_mode='bop19')[0] == pytest.approx(1.0)


def test_vsd_depth_shift_counts_only_beyond_tau(box_scene):
    renderer, intr, T_gt, depth = box_scene
    nearer = T_gt.copy()
    nearer[2, 3] -= 0.010  # 10 mm towards the camera: within tau = 20 mm
    assert vsd(nearer, T_gt, depth, intr, renderer)[0] < 0.15
    errors = vsd(nearer, T_gt, depth, intr, renderer, taus_m=(0.005, 0.020))
    assert errors[0] > 0.7 and errors[1] < errors[0]
    # the symmetric equivalent (180° about the box's z) is indistinguishable
    flipped = T_gt @ _pose((0, 0, 1), 180, (0, 0, 0))
    assert vsd(flipped, T_gt, depth, intr, renderer)[0] == pytest.approx(0.0, abs=0.02)


def test_box_iou():
    assert box_iou((0, 0, 10, 10), (0, 0, 10, 10)) == 1.0
    assert box_iou((0, 0, 10, 10), (5, 0, 10, 10)) == pytest.approx(50 / 150)
    assert box_iou((0, 0, 10, 10), (20, 20, 5, 5)) == 0.0
    with pytest.raises(ValueError):
        box_iou((0, 0, -1, 1), (0, 0, 1, 1))


def test_recalls():
    errors = np.array([0.1, 0.2, 0.3, np.nan])
    assert recall(errors, 0.3) == 0.5
    assert recall(errors, 0.3, strict=False) == 0.75
    assert np.isnan(recall([], 0.3))
    assert average_recall(np.array([0.07, 0.5]), BOP19_THRESHOLDS) == pytest.approx(0.9 / 2)


def test_duplicates_count_poses_of_one_part_whatever_their_class():
    from tlessbot_ros.core.metrics import count_duplicates

    apart = np.array([[0.0, 0, 0.6], [0.08, 0, 0.6], [0, 0.1, 0.6]])
    assert count_duplicates(apart) == 0
    assert count_duplicates(apart[:1]) == 0 and count_duplicates(np.zeros((0, 3))) == 0
    twice = np.vstack([apart, apart[1] + [0.004, -0.003, 0.002]])
    assert count_duplicates(twice) == 1
    thrice = np.vstack([twice, apart[1] + [-0.01, 0.0, 0.0]])
    assert count_duplicates(thrice) == 2
    assert count_duplicates(thrice, radius_m=0.001) == 0


def test_two_small_parts_side_by_side_are_no_duplicate_of_one_another():
    from tlessbot_ros.core.metrics import DUPLICATE_RADIUS_M, count_duplicates, duplicate_radius_m

    nut = duplicate_radius_m(np.array([0.008, 0.0092, 0.0063]))   # an 8 mm hex nut
    assert nut == pytest.approx(0.004)
    assert duplicate_radius_m(np.array([0.2, 0.08, 0.01])) == DUPLICATE_RADIUS_M
    two_nuts = np.array([[0.0, 0, 0.6], [0.022, 0, 0.6]])          # 22 mm apart
    assert count_duplicates(two_nuts) == 1                       # the fixed radius joined them
    assert count_duplicates(two_nuts, radius_m=np.array([nut, nut])) == 0
    one_nut_twice = np.array([[0.0, 0, 0.6], [0.001, 0.001, 0.6]])
    assert count_duplicates(one_nut_twice, radius_m=np.array([nut, nut])) == 1
    # a nut beside a large part: the smaller radius of the pair decides
    assert count_duplicates(two_nuts, radius_m=np.array([nut, DUPLICATE_RADIUS_M])) == 0
