"""Near-symmetric turns: a disc with four small holes nearly fits its depth at any turn about
its axis; the colour image's edges (the holes) tell the turns apart."""
from __future__ import annotations

import numpy as np
import pytest
from side_scene import SIDE, side_scene

from tlessbot_ros.core.common import (
    depth_to_points,
    make_transform,
    rotation_about_axis,
    rotation_angle_deg,
)
from tlessbot_ros.core.pose import (
    PoseParams,
    Refiner,
    TurnParams,
    build_database,
    choose_turn,
    near_turns,
    rendered_edges,
    resting_pose,
)
from tlessbot_ros.core.pose.flat import ViewEvidence, mesh_scene
from tlessbot_ros.core.pose.turns import surface_centre
from tlessbot_ros.tools.support import part_generator as gen


def _disc(small_holes: bool):
    """A disc 44 mm across and 8 mm thick with a 12 mm hole in its centre and, with
    ``small_holes``, four 4.4 mm holes on a circle: (vertices m, faces), its templates."""
    holes = gen._holes([(0, 0, 0)], 6.0)
    if small_holes:
        holes += gen._holes([(15, 0, 0), (-15, 0, 0), (0, 15, 0), (0, -15, 0)], 2.2)
    sdf = gen._minus(gen._cylinder((0, 0, 4), 22, 4), *holes)
    v, f = gen.mesh_part(sdf, np.array([-23.0, -23, -1]), np.array([23.0, 23, 9]),
                         spacing_mm=0.7)
    v = v / 1000.0
    db = build_database([(1, v, f, [(resting_pose(v), 1.0)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    return v, f, db[1]


@pytest.fixture(scope='module')
def holed_disc():
    return _disc(True)


def _turn(obj, angle_deg: float) -> np.ndarray:
    """The turn by ``angle_deg`` about the model z axis through the surface centroid."""
    centre = surface_centre(obj)
    R = rotation_about_axis([0.0, 0.0, 1.0], np.radians(angle_deg))
    return make_transform(R, centre - R @ centre)


def _angle_about(S: np.ndarray, axis) -> float:
    """The turn's angle (deg) when it turns about ``axis`` (either way), else nan."""
    w, V = np.linalg.eig(S[:3, :3])
    a = np.real(V[:, np.argmin(np.abs(w - 1))])
    if abs(a @ np.asarray(axis, float)) < 0.99:
        return float('nan')
    return rotation_angle_deg(S[:3, :3], np.eye(3))


def test_templates_keep_the_mesh_of_a_thick_part(holed_disc):
    _, _, obj = holed_disc
    assert obj.mesh_faces is not None and mesh_scene(obj) is not None


def test_near_turns_are_the_turns_the_small_holes_break(holed_disc):
    _, _, obj = holed_disc
    angles = [_angle_about(S, [0, 0, 1]) for S in near_turns(obj)]
    about_axis = sorted(a for a in angles if np.isfinite(a))
    # every 5°, but the exact symmetries (90°, 180°) and their neighbours within
    # min_turn_deg; the small turns too: the disc nearly turns on its axis at every angle
    rounded = set(np.round(about_axis))
    assert {5.0, 10.0, 30.0, 45.0, 60.0} <= rounded
    assert all(min(abs(a - 90.0), abs(a - 180.0)) >= TurnParams().min_turn_deg - 1e-6
               for a in about_axis)
    # without the small holes every turn about the axis is exact: none is listed
    _, _, plain = _disc(False)
    assert not any(np.isfinite(_angle_about(S, [0, 0, 1])) for S in near_turns(plain))


def test_listed_symmetries_are_the_exact_turns():
    # a disc whose holes the sampling cannot see (here: none beside the centre bore) listed
    # 4-fold, as its bolt holes make it: the mesh test reads every turn about its axis as
    # exact, the listed symmetries only the quarter turns; the others are near, asked of the
    # colour image
    from tlessbot_ros.core.common import Symmetries
    v, f, plain = _disc(False)
    four = Symmetries(discrete=tuple(
        make_transform(rotation_about_axis([0, 0, 1], np.radians(90.0 * k)), [0, 0, 0])
        for k in (1, 2, 3)))
    db = build_database([(1, v, f, [(resting_pose(v), 1.0)], None)], symmetries={1: four},
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    assert db[1].listed_rotations is not None and len(db[1].listed_rotations) == 4
    angles = [_angle_about(S, [0, 0, 1]) for S in near_turns(db[1])]
    rounded = set(np.round([a for a in angles if np.isfinite(a)]))
    assert {30.0, 45.0, 60.0} <= rounded
    assert not rounded & {80.0, 85.0, 90.0, 95.0, 100.0, 180.0}
    assert not any(np.isfinite(_angle_about(S, [0, 0, 1])) for S in near_turns(plain))


def _scene(vertices, faces, T_world_object, *, noise_m=0.0005, seed=0):
    return side_scene(vertices, faces, T_world_object, noise_m=noise_m, seed=seed, shaded=True)


@pytest.mark.parametrize('wrong_deg', [30.0, -20.0, 45.0, 8.0])
def test_choose_turn_finds_the_holes_on_the_image(holed_disc, wrong_deg):
    v, f, obj = holed_disc
    T_world_object = make_transform(rotation_about_axis([0, 0, 1], np.radians(17)),
                                    [0.01, -0.015, 0.0])
    rgb, depth, mask = _scene(v, f, T_world_object)
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask)
    T_true = np.linalg.inv(SIDE.T_world_camera) @ T_world_object
    refiner = Refiner(PoseParams())
    views = [ViewEvidence(rgb, mask, SIDE.intrinsics, np.eye(4))]

    def fitness(T):
        return refiner.grid_fitness(T, points, obj)

    def error_deg(T):   # about the axis, modulo the disc's 90° symmetry
        return min(rotation_angle_deg(T[:3, :3], (T_true @ _turn(obj, 90.0 * k))[:3, :3])
                   for k in range(4))

    T_wrong = T_true @ _turn(obj, wrong_deg)
    # the depth alone cannot tell: the turned disc fits it as well
    assert fitness(T_wrong[None])[0] > fitness(T_true[None])[0] - 0.05
    turned, info = choose_turn(obj, mesh_scene(obj), T_wrong, views, fitness, TurnParams())
    assert info['turned_deg'] > 0 and error_deg(turned) < 5.0, sorted(info.items())
    assert info['best_support'] > info['support']
    kept, info = choose_turn(obj, mesh_scene(obj), T_true, views, fitness, TurnParams())
    assert info['turned_deg'] == 0.0 and np.array_equal(kept, T_true)


def test_choose_turn_leaves_a_part_without_colour_or_turns(holed_disc):
    v, f, obj = holed_disc
    T = np.linalg.inv(SIDE.T_world_camera) @ make_transform(np.eye(3), [0.0, 0.0, 0.0])
    kept, info = choose_turn(obj, mesh_scene(obj), T, [], lambda poses: np.ones(len(poses)),
                             TurnParams())
    assert np.array_equal(kept, T) and info['turned_deg'] == 0.0


def test_rendered_edges_show_the_rim_of_a_hole(holed_disc):
    v, f, obj = holed_disc
    T = np.linalg.inv(SIDE.T_world_camera) @ make_transform(np.eye(3), [0.0, 0.0, 0.0])
    box = (250, 170, 140, 140)
    edges = rendered_edges(mesh_scene(obj), T, SIDE.intrinsics, box, jump_m=0.002,
                           crease_deg=30.0)
    _, _, mask = _scene(v, f, make_transform(np.eye(3), [0.0, 0.0, 0.0]), noise_m=0.0)
    x0, y0, w, h = box
    part = mask[y0:y0 + h, x0:x0 + w]
    assert part.any() and edges.any()
    # the outline and the holes' rims: edge pixels lie inside the part's box, on its border
    # or next to a hole, never far out on the table
    rows, cols = np.nonzero(part)
    assert np.all(np.nonzero(edges)[0] >= rows.min() - 1)
    assert np.count_nonzero(edges & part) > 0.05 * np.count_nonzero(part)


def test_turn_params_reject_bad_values():
    with pytest.raises(ValueError, match='step_deg'):
        TurnParams(step_deg=0.0)
    with pytest.raises(ValueError, match='min_gain'):
        TurnParams(min_gain=2.0)


def _listed_turns(obj) -> bool:
    return any(isinstance(key, tuple) and len(key) == 2 and isinstance(key[1], tuple)
               and key[1][:1] == ('near_turns',) for key in obj._cache)


def test_turns_are_listed_at_warm_up_only_where_frames_bring_colour():
    """A pose node without colour input never runs the check: its start-up lists no turns."""
    from types import SimpleNamespace

    from tlessbot_ros.core.params import FitParams
    from tlessbot_ros.core.turn_check import warm_up_turns

    _, _, obj = _disc(False)
    database = SimpleNamespace(objects={1: obj})
    warm_up_turns(database, FitParams(), colour=False)
    assert not _listed_turns(obj)
    warm_up_turns(database, FitParams())
    assert _listed_turns(obj)
