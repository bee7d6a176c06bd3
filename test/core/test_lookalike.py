"""core.lookalike: finding look-alike parts, whether a view shows their difference, and telling
them apart from a fitted pose and an ROI cloud; template databases keep their meshes."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    MeshRenderer,
    depth_to_points,
    make_transform,
    raycasting_scene,
)
from tlessbot_ros.core.pose import (
    POINT_QUANTUM_M,
    LookalikeCheck,
    ObjectTemplates,
    TemplateDatabase,
    clear_margin,
    depth_errors,
    depth_vote,
    lookalike_pairs,
    shared_surface,
    visible_difference,
    vote_counts,
)
from tlessbot_ros.errors import ModelFileError

CAMERA = CameraIntrinsics(320, 240, np.array([[600.0, 0.0, 160.0], [0.0, 600.0, 120.0],
                                               [0.0, 0.0, 1.0]]))
# faces of a box from its 8 corners ordered (x, y, z) in {-, +}^3, outward normals
BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], np.int32)


def _box(lo, hi):
    vertices = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                         for z in (lo[2], hi[2])], np.float64)
    return vertices, BOX_FACES.copy()


def _union(*meshes):
    vertices, faces, offset = [], [], 0
    for v, f in meshes:
        vertices.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.vstack(vertices), np.vstack(faces)


PLAIN = _box((-0.03, -0.02, -0.015), (0.03, 0.02, 0.015))
# the same block with a 15 x 15 x 6 mm boss on its +z face: a look-alike
BOSSED = _union(PLAIN, _box((-0.0075, -0.0075, 0.015), (0.0075, 0.0075, 0.021)))
OTHER = _box((-0.04, -0.01, -0.01), (0.04, 0.01, 0.01))


def _seen_from_above(mesh, T_camera_object, noise_m=0.0, seed=0):
    """ROI cloud (N, 3) of one mesh rendered alone by CAMERA, with Gaussian depth noise."""
    renderer = MeshRenderer()
    renderer.add_mesh(*mesh)
    depth = renderer.render(CAMERA, np.linalg.inv(T_camera_object)).depth_m
    depth = depth + (depth > 0) * np.random.default_rng(seed).normal(0, noise_m, depth.shape)
    points, _ = depth_to_points(depth.astype(np.float32), CAMERA.K)
    return points, depth > 0


# camera 0.5 m above the part, looking down its -z (boss up) or its +z (boss down)
BOSS_UP = make_transform(np.diag([1.0, -1.0, -1.0]), [0.0, 0.0, 0.5])
BOSS_DOWN = make_transform(np.eye(3), [0.0, 0.0, 0.5])


def test_pairs_are_found_by_shared_surface():
    assert shared_surface(PLAIN, PLAIN) == pytest.approx(1.0)
    shared = shared_surface(PLAIN, BOSSED)
    assert 0.85 < shared < 1.0   # the boss's sides and top are not on the plain block
    assert shared_surface(PLAIN, OTHER) < 0.5
    assert lookalike_pairs({1: PLAIN, 2: BOSSED, 3: OTHER}) == {1: (2,), 2: (1,)}
    assert lookalike_pairs({1: PLAIN, 2: BOSSED}, min_shared=0.999) == {}


def test_a_view_shows_the_difference_only_when_it_sees_the_boss():
    _, mask_up = _seen_from_above(BOSSED, BOSS_UP)
    _, mask_down = _seen_from_above(BOSSED, BOSS_DOWN)
    bossed, plain = raycasting_scene(*BOSSED), raycasting_scene(*PLAIN)
    up = visible_difference(bossed, plain, BOSS_UP, CAMERA, mask_up)
    down = visible_difference(bossed, plain, BOSS_DOWN, CAMERA, mask_down)
    # the boss covers 225 of the 2400 mm^2 of the top face that the camera sees
    assert 0.05 < up < 0.15
    assert down == 0.0
    assert visible_difference(bossed, plain, BOSS_UP, CAMERA, np.zeros_like(mask_up)) == 0.0


def test_depth_vote_counts_pixels_beyond_the_tolerance():
    assert depth_vote(np.zeros(4), np.array([0.0, 0.0, 0.005, 0.005]), 0.002) == 0.5
    assert depth_vote(np.array([0.0, 0.0, 0.005, 0.005]), np.zeros(4), 0.002) == -0.5
    assert depth_vote(np.zeros(4), np.full(4, 0.001), 0.002) == 0.0
    assert depth_vote(np.zeros(0), np.zeros(0), 0.002) == 0.0


@pytest.mark.parametrize('truth', [1, 2])
def test_check_names_the_part_whose_surface_explains_the_depth(truth):
    check = LookalikeCheck({1: PLAIN, 2: BOSSED}, {1: (2,), 2: (1,)})
    points, _ = _seen_from_above({1: PLAIN, 2: BOSSED}[truth], BOSS_UP, noise_m=0.001)
    for fitted_as in (1, 2):
        winner, vote = check.resolve(fitted_as, BOSS_UP, points)
        assert winner == truth
        assert (vote > 0.05) if fitted_as != truth else vote == 0.0
    # boss turned away from the camera: nothing to tell them apart, the fitted class stays
    points, _ = _seen_from_above({1: PLAIN, 2: BOSSED}[truth], BOSS_DOWN, noise_m=0.001)
    assert check.resolve(1, BOSS_DOWN, points)[0] == 1
    assert check.resolve(2, BOSS_DOWN, points)[0] == 2
    # a part without look-alikes, or no points, is left alone
    assert 3 not in check and check.resolve(3, BOSS_UP, points) == (3, 0.0)
    assert check.resolve(1, BOSS_UP, np.zeros((0, 3))) == (1, 0.0)


def _object(obj_id, mesh=None, lookalikes=()):
    points = np.random.default_rng(obj_id).normal(0, 0.01, (50, 3)).astype(np.float32)
    return ObjectTemplates(
        obj_id=obj_id, diameter_m=0.08, voxel_size_m=0.003, model_points=points,
        model_normals=points / np.linalg.norm(points, axis=1, keepdims=True),
        stable_poses=np.eye(4)[None], stable_probabilities=np.ones(1),
        yaw_periods=np.full(1, 2 * np.pi), lookalikes=lookalikes,
        mesh_vertices=None if mesh is None else mesh[0].astype(np.float32),
        mesh_faces=None if mesh is None else mesh[1])


def test_database_keeps_lookalike_meshes(tmp_path):
    db = TemplateDatabase({1: _object(1, PLAIN, (2,)), 2: _object(2, BOSSED, (1,)),
                           3: _object(3)})
    path = tmp_path / 'db.npz'
    db.save(path)
    loaded = TemplateDatabase.load(path)
    assert loaded[1].lookalikes == (2,) and loaded[2].lookalikes == (1,)
    assert loaded[3].lookalikes == () and loaded[3].mesh_faces is None
    np.testing.assert_array_equal(loaded[2].mesh_faces, BOSSED[1])
    np.testing.assert_allclose(loaded[2].mesh_vertices, BOSSED[0], atol=POINT_QUANTUM_M)
    check = loaded.lookalike_check()
    assert 1 in check and 2 in check and 3 not in check
    points, _ = _seen_from_above(BOSSED, BOSS_UP)
    assert check.resolve(1, BOSS_UP, points)[0] == 2


def test_database_with_a_broken_mesh_is_refused(tmp_path):
    path = tmp_path / 'db.npz'
    TemplateDatabase({2: _object(2, BOSSED, ())}).save(path)
    with np.load(path) as data:
        arrays = dict(data)
    arrays['o2_mesh_faces'] = arrays['o2_mesh_faces'] + 1000   # indices past the vertices
    np.savez(path, **arrays)
    with pytest.raises(ModelFileError, match='inconsistent mesh'):
        TemplateDatabase.load(path)


def test_version_2_database_loads_without_lookalikes(tmp_path):
    path = tmp_path / 'db.npz'
    TemplateDatabase({1: _object(1, PLAIN, (2,)), 2: _object(2, BOSSED, (1,))}).save(path)
    with np.load(path) as data:
        arrays = {k: v for k, v in data.items() if 'mesh' not in k and 'lookalikes' not in k}
    arrays['version'] = np.array(2)
    np.savez(path, **arrays)
    loaded = TemplateDatabase.load(path)
    assert loaded[1].lookalikes == () and loaded[1].mesh_faces is None
    assert 1 not in loaded.lookalike_check()


def test_vote_counts_and_the_clear_margin():
    assert vote_counts(np.zeros(5), np.array([0.0, 0.005, 0.005, 0.001, -0.004]), 0.002) == (2, 1)
    assert clear_margin(20, 2, 2.0) and not clear_margin(2, 0, 2.0)   # 2 > 2 * sqrt(2)? no
    assert clear_margin(2, 0, 0.0) and not clear_margin(3, 3, 0.0) and not clear_margin(0, 0, 0)
    assert not clear_margin(13, 11, 2.0)   # an even split stays a coin toss


def test_a_few_pixels_do_not_overturn_the_fitted_class():
    points, _ = _seen_from_above(BOSSED, BOSS_UP, noise_m=0.0005)
    errors_plain = depth_errors(raycasting_scene(*PLAIN), BOSS_UP, points)
    on_boss = np.flatnonzero(errors_plain > 0.004)
    assert len(on_boss) > 100
    few = np.concatenate([np.flatnonzero(errors_plain <= 0.004), on_boss[:2]])
    strict = LookalikeCheck({1: PLAIN, 2: BOSSED}, {1: (2,), 2: (1,)}, min_z=2.0)
    loose = LookalikeCheck({1: PLAIN, 2: BOSSED}, {1: (2,), 2: (1,)}, min_z=0.0)
    assert loose.resolve(1, BOSS_UP, points[few])[0] == 2    # two pixels decide
    assert strict.resolve(1, BOSS_UP, points[few]) == (1, 0.0)
    assert strict.resolve(1, BOSS_UP, points)[0] == 2        # the whole boss does


@pytest.mark.parametrize('truth', [1, 2])
def test_a_second_camera_that_sees_the_feature_decides(truth):
    mesh = {1: PLAIN, 2: BOSSED}[truth]
    down, _ = _seen_from_above(mesh, BOSS_DOWN, noise_m=0.0005)
    up, _ = _seen_from_above(mesh, BOSS_UP, noise_m=0.0005, seed=1)
    T_up_down = BOSS_UP @ np.linalg.inv(BOSS_DOWN)   # the first camera in the second's frame
    check = LookalikeCheck({1: PLAIN, 2: BOSSED}, {1: (2,), 2: (1,)}, min_z=2.0)
    for fitted_as in (1, 2):
        assert check.resolve(fitted_as, BOSS_DOWN, down)[0] == fitted_as   # cannot tell
        winner, vote = check.resolve(fitted_as, BOSS_DOWN, down, more_views=[(up, T_up_down)])
        assert winner == truth
        assert (vote > 0.02) if fitted_as != truth else vote == 0.0
    # a view without points adds nothing
    assert check.resolve(1, BOSS_DOWN, down, more_views=[(np.zeros((0, 3)), T_up_down)]) == \
        (1, 0.0)


def _holed_plate(hole_y):
    """A 60 x 40 x 4 mm plate with a 6 x 6 mm through-hole centred at (15 mm, ``hole_y``)."""
    lo, hi = hole_y - 0.003, hole_y + 0.003
    return _union(_box((-0.03, -0.02, -0.002), (0.012, 0.02, 0.002)),
                  _box((0.018, -0.02, -0.002), (0.03, 0.02, 0.002)),
                  _box((0.012, -0.02, -0.002), (0.018, lo, 0.002)),
                  _box((0.012, hi, -0.002), (0.018, 0.02, 0.002)))


# mirror twins: the hole on either side of the plate's long axis
HOLE_LEFT, HOLE_RIGHT = _holed_plate(0.01), _holed_plate(-0.01)


def test_each_twin_refined_on_the_depth_names_a_part_fitted_off_its_hole():
    points, _ = _seen_from_above(HOLE_LEFT, BOSS_UP, noise_m=0.0005)
    off = BOSS_UP @ make_transform(np.eye(3), [0.006, 0.0, 0.0])   # 6 mm off along the plate
    twins = {1: HOLE_LEFT, 2: HOLE_RIGHT}, {1: (2,), 2: (1,)}
    check = LookalikeCheck(*twins, min_z=2.0)
    # where the fitted pose stands, each twin's hole lies on the plate: the pixels split
    assert check.resolve(2, off, points) == (2, 0.0)
    winner, vote = check.resolve(2, off, points, refine=True)
    assert winner == 1 and vote > 0.01
    assert check.resolve(1, off, points, refine=True) == (1, 0.0)
    # the true pose needs no refinement, and refining it changes nothing
    assert check.resolve(2, BOSS_UP, points)[0] == 1
    assert check.resolve(2, BOSS_UP, points, refine=True)[0] == 1
