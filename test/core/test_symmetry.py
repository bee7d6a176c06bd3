"""Symmetry representation, models_info parsing and detection on the T-LESS CAD models."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import (
    Symmetries,
    detect_symmetries,
    make_transform,
    rotation_about_axis,
    sample_surface,
    symmetries_from_models_info,
    symmetries_to_models_info,
)

# BOP's published groups for T-LESS (models_info.json); only some models are on disk here.
CONTINUOUS = {1, 2, 3, 4, 13, 14, 15, 16, 17, 24, 30}
TWO_FOLD = {5, 6, 7, 8, 9, 10, 11, 12, 19, 20, 23, 25, 26, 28, 29}
FOUR_FOLD = {27}
NONE = {18, 21, 22}
AVAILABLE = [2, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 19, 20, 21, 22, 23, 24, 25, 26, 30]


def _expected(obj_id: int) -> str:
    if obj_id in CONTINUOUS:
        return 'continuous'
    if obj_id in TWO_FOLD:
        return '2-fold'
    if obj_id in FOUR_FOLD:
        return '4-fold'
    return 'none'


def _box_mesh(size):
    sx, sy, sz = (s / 2 for s in size)
    v = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def test_symmetries_always_hold_identity_first():
    flip = make_transform(rotation_about_axis([0, 0, 1], np.pi), np.zeros(3))
    s = Symmetries(discrete=(flip,))
    assert len(s.discrete) == 2
    assert np.allclose(s.discrete[0], np.eye(4))
    assert Symmetries().is_trivial and not s.is_trivial


def test_transforms_discretise_continuous_axes():
    s = Symmetries(discrete=(make_transform(rotation_about_axis([1, 0, 0], np.pi), np.zeros(3)),),
                   continuous=(([0, 0, 2.0], [0.0, 0.0, 0.0]),))
    T = s.transforms(step_rad=np.radians(10))
    assert T.shape == (36 * 2, 4, 4)
    assert np.allclose(T[0], np.eye(4))
    # every element maps the z axis to +-z
    assert np.allclose(np.abs(T[:, 2, 2]), 1.0)


def test_models_info_round_trip_in_mm():
    entry = {'symmetries_discrete': [[-1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1, 5.0, 0, 0, 0, 1]],
             'symmetries_continuous': [{'axis': [0, 0, 1], 'offset': [0, 0, 10.0]}]}
    s = symmetries_from_models_info(entry)
    assert len(s.discrete) == 2
    assert s.discrete[1][2, 3] == pytest.approx(0.005)
    assert np.allclose(s.continuous[0][1], [0, 0, 0.010])
    back = symmetries_to_models_info(s)
    assert np.allclose(back['symmetries_discrete'][0], entry['symmetries_discrete'][0])
    assert np.allclose(back['symmetries_continuous'][0]['offset'], [0, 0, 10.0])
    assert symmetries_from_models_info({}).is_trivial
    with pytest.raises(ValueError, match='16 numbers'):
        symmetries_from_models_info({'symmetries_discrete': [[1, 0, 0]]})


def test_sample_surface_lies_on_the_box():
    v, f = _box_mesh((0.1, 0.06, 0.04))
    p, n = sample_surface(v, f, 2000, seed=1, scheme='sqrt')
    on_face = np.isclose(np.abs(p), [0.05, 0.03, 0.02], atol=1e-9).any(axis=1)
    assert on_face.all()
    assert np.all(np.abs(p) <= [0.05 + 1e-9, 0.03 + 1e-9, 0.02 + 1e-9])
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0)


def test_sample_surface_schemes_are_uniform_and_seeded():
    v, f = _box_mesh((0.1, 0.06, 0.04))
    reflect, _ = sample_surface(v, f, 20000, seed=3)
    sqrt, _ = sample_surface(v, f, 20000, seed=3, scheme='sqrt')
    assert not np.allclose(reflect, sqrt)     # the same seed, other points
    for p in (reflect, sqrt):                  # both uniform: the box centre is the mean
        np.testing.assert_allclose(p.mean(axis=0), 0.0, atol=1.5e-3)
    np.testing.assert_array_equal(sample_surface(v, f, 50, seed=3)[0],
                                  sample_surface(v, f, 50, seed=3)[0])
    with pytest.raises(ValueError, match='scheme'):
        sample_surface(v, f, 10, scheme='grid')


def test_detects_the_three_flips_of_a_box():
    v, f = _box_mesh((0.1, 0.06, 0.04))
    s = detect_symmetries(v, f)
    assert not s.continuous
    assert len(s.discrete) == 4  # identity + 180° about x, y and z


@pytest.mark.parametrize('obj_id', [
    pytest.param(i, marks=pytest.mark.xfail(
        strict=True, reason='obj_25: the 180° flip leaves 20 % of the surface > 1 % of the '
        'diameter away (more than obj_21, which BOP lists as asymmetric)'))
    if i == 25 else i for i in AVAILABLE])
def test_detection_matches_bop_groups(tless_models_dir, obj_id):
    trimesh = pytest.importorskip('trimesh')
    mesh = trimesh.load(tless_models_dir / f'obj_{obj_id:02d}.stl')
    s = detect_symmetries(np.asarray(mesh.vertices) / 1000.0, np.asarray(mesh.faces))
    expected = _expected(obj_id)
    if expected == 'continuous':
        assert len(s.continuous) == 1
        assert abs(s.continuous[0][0][2]) > 0.99  # T-LESS models turn about their z axis
    else:
        assert not s.continuous
        assert s.describe() == expected


def test_axis_point_ignores_the_tiny_singular_value_along_the_axis():
    from tlessbot_ros.core.common import make_transform, rotation_about_axis
    from tlessbot_ros.core.common.symmetry_detect import _axis_point

    axis = np.array([1e-4, -2e-4, 1.0])
    centre = np.array([0.01, -0.02, 0.0])
    R = rotation_about_axis(axis, np.radians(60)) @ rotation_about_axis([1, 0, 0], 1e-6)
    T = make_transform(R, centre - R @ centre + np.array([0, 0, 1e-7]))
    point = _axis_point(T)
    assert np.linalg.norm(point[:2] - centre[:2]) < 1e-3 and abs(point[2]) < 0.01


def _tube(shift_m: float):
    trimesh = pytest.importorskip('trimesh')
    mesh = trimesh.creation.annulus(r_min=0.008, r_max=0.012, height=0.06, sections=64)
    return np.asarray(mesh.vertices) + [0.0, 0.0, shift_m], np.asarray(mesh.faces)


@pytest.mark.parametrize('shift_m', [0.0, 0.03])
def test_tube_with_alike_ends_is_continuous_and_two_fold(shift_m):
    # a tube's two ends are alike: turning about its axis and flipping end for end both map
    # it onto itself, wherever the CAD origin lies on the axis (here at the centre or an end)
    v, f = _tube(shift_m)
    s = detect_symmetries(v, f)
    assert s.describe() == 'continuous + 2-fold'
    axis, offset = s.continuous[0]
    assert abs(axis[2]) > 0.999
    assert abs(offset[2] - shift_m) < 1e-3
    flip = s.discrete[1]
    ends = np.array([[0.0, 0.0, shift_m - 0.03], [0.0, 0.0, shift_m + 0.03]])
    moved = ends @ flip[:3, :3].T + flip[:3, 3]
    assert np.allclose(moved, ends[::-1], atol=1e-3)
    # every composed transform maps the surface onto itself
    points, _ = sample_surface(v, f, 400, seed=3)
    radius = np.hypot(points[:, 0], points[:, 1])
    for T in s.transforms(step_rad=np.radians(40)):
        p = points @ T[:3, :3].T + T[:3, 3]
        assert np.all(np.abs(np.hypot(p[:, 0], p[:, 1]) - radius) < 1e-3)
        assert np.all((p[:, 2] > shift_m - 0.0305) & (p[:, 2] < shift_m + 0.0305))


def test_lying_tube_yaw_period_is_half_a_turn_with_the_origin_at_an_end():
    from tlessbot_ros.core.pose import yaw_period

    v, f = _tube(0.03)
    T = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi / 2), [0.0, 0.0, 0.012])
    assert yaw_period(v, f, T, tolerance_m=0.001) == pytest.approx(np.pi)


def _plate(holes_mm):
    """A plate 60 x 40 x 4 mm with through holes 5.2 mm wide at ``holes_mm`` ((x, y) mm):
    (vertices m, faces)."""
    from tlessbot_ros.tools.support.part_generator import mesh_part

    def sdf(x, y, z):
        d = np.maximum(np.maximum(np.abs(x) - 30.0, np.abs(y) - 20.0), np.abs(z - 2.0) - 2.0)
        for hx, hy in holes_mm:
            d = np.maximum(d, 2.6 - np.hypot(x - hx, y - hy))
        return d
    vertices, faces = mesh_part(sdf, np.array([-31.0, -21.0, -1.0]),
                                np.array([31.0, 21.0, 5.0]), spacing_mm=0.5)
    return vertices / 1000.0, faces


def test_a_plate_with_one_off_centre_hole_has_no_symmetry():
    from tlessbot_ros.core.common import SymmetryParams

    # the plate alone, and with a hole in its centre: the three half turns of a box
    assert detect_symmetries(*_plate([])).describe() == '4-fold'
    assert detect_symmetries(*_plate([(0.0, 0.0)])).describe() == '4-fold'
    # one hole off the centre: every half turn moves it, nothing maps the plate onto itself
    holed = _plate([(15.0, -10.0)])
    assert detect_symmetries(*holed).is_trivial, detect_symmetries(*holed).describe()
    # the surface test alone (the outline test off) is blind to it: the hole is about 1 % of
    # the surface, well inside the quantile the test forgives
    assert not detect_symmetries(*holed, params=SymmetryParams(flat_ratio=0.0)).is_trivial


def test_a_flange_with_four_bolt_holes_is_four_fold_not_continuous():
    # a disc whose bolt holes break its continuous symmetry: the 4-fold turn about its axis
    # and four half turns, a group of 8 (the scan's flip a degree off used to make it 48)
    from tlessbot_ros.tools.support.part_generator import mesh_part, part_shapes

    sdf, (low, high) = part_shapes()['disc_flange']
    vertices, faces = mesh_part(sdf, low, high, spacing_mm=0.5)
    s = detect_symmetries(vertices / 1000.0, faces)
    assert not s.continuous and s.describe() == '8-fold'
