"""Look-alike twins on a smoothed, stereo-like depth (the simulator's ``smoothed`` kind): a plate
and its twin with one 6 mm hole more. The smoothed depth reads the hole shut, so the depth's
look-alike check names the twin without it; the shaded colour image still shows the hole's rim,
and the twins are named on the image's edges first (``FitParams.lookalike_edge_min_z``,
:func:`~tlessbot_ros.core.flat_parts.twins_on_edges`)."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from side_scene import SIDE, side_scene

from tlessbot_ros.core.common import (
    depth_to_points,
    make_transform,
    rotation_about_axis,
    transform_points,
)
from tlessbot_ros.core.frame import ViewInput
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import build_database
from tlessbot_ros.sim.noise import DepthNoiseParams, add_depth_noise

PLAIN, HOLED = 1, 2


def _boxes(*boxes):
    """One mesh of axis-aligned boxes ((x0, y0, z0), (x1, y1, z1)) in metres."""
    trimesh = pytest.importorskip('trimesh')
    meshes = [trimesh.creation.box(extents=np.subtract(hi, lo), transform=make_transform(
        np.eye(3), np.add(lo, hi) / 2)) for lo, hi in boxes]
    mesh = trimesh.util.concatenate(meshes)
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.fixture(scope='module')
def twins():
    """A plate 60 x 40 x 6 mm with an 8 mm square hole near a corner (PLAIN: no symmetry, as
    the generated twins) and its twin with a 6 mm square hole more (HOLED): their meshes and
    templates (side camera)."""
    left = [((0, 0, 0), (0.008, 0.04, 0.006)), ((0.008, 0, 0), (0.016, 0.008, 0.006)),
            ((0.008, 0.016, 0), (0.016, 0.04, 0.006))]
    plain = _boxes(*left, ((0.016, 0, 0), (0.06, 0.04, 0.006)))
    holed = _boxes(*left, ((0.016, 0, 0), (0.036, 0.04, 0.006)),
                   ((0.042, 0, 0), (0.06, 0.04, 0.006)),
                   ((0.036, 0, 0), (0.042, 0.022, 0.006)),
                   ((0.036, 0.028, 0), (0.042, 0.04, 0.006)))
    flipped = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi), [0, 0.04, 0.006])
    poses = [(np.eye(4), 0.5), (flipped, 0.5)]
    db = build_database([(PLAIN, *plain, poses, None), (HOLED, *holed, poses, None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    assert db[PLAIN].lookalikes == (HOLED,) and db[HOLED].lookalikes == (PLAIN,)
    return {PLAIN: plain, HOLED: holed}, db


def _frame(meshes, shown: int, yaw_deg: float = 25.0, depth_kind: str = 'smoothed'):
    """Part ``shown`` on the table seen by the side camera: its shaded colour image and a
    smoothed (or ``depth_kind``) depth; the outline's pixels with the hole filled (a
    localiser's closed mask) label it. Returns (inputs, labels, T_camera_object true, ROI
    points)."""
    T_world_object = make_transform(rotation_about_axis([0, 0, 1], np.radians(yaw_deg)),
                                    [0.005, -0.01, 0.0])
    rgb, clean, _ = side_scene(*meshes[shown], T_world_object, noise_m=0.0, shaded=True)
    _, _, outline = side_scene(*meshes[PLAIN], T_world_object, noise_m=0.0)
    depth_mm = add_depth_noise(clean, float(SIDE.intrinsics.K[0, 0]), np.random.default_rng(3),
                               DepthNoiseParams(kind=depth_kind))
    depth = depth_mm.astype(np.float32) / 1000.0
    inputs = {'side': ViewInput(rgb=rgb, depth_m=depth, intrinsics=SIDE.intrinsics,
                                T_world_camera=SIDE.T_world_camera)}
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=outline & (depth > 0))
    T_true = np.linalg.inv(SIDE.T_world_camera) @ T_world_object
    return inputs, {'side': outline.astype(np.uint16)}, T_true, points


def test_the_smoothed_depth_names_the_twin_without_the_hole(twins):
    # the failure this check answers: at the true pose, the depth (hole read shut) names the
    # plain twin by a clear margin though the part has the hole
    meshes, db = twins
    _, _, T_true, points = _frame(meshes, HOLED)
    check = db.lookalike_check(min_z=FitParams().lookalike_min_z)
    winner, _ = check.resolve(HOLED, T_true, points, T_world_camera=SIDE.T_world_camera)
    assert winner == PLAIN


@pytest.mark.parametrize('named', [PLAIN, HOLED])
def test_the_hole_s_rim_on_the_image_names_the_part(twins, named):
    meshes, db = twins
    inputs, labels, _, _ = _frame(meshes, HOLED)
    [found] = PerceptionPipeline(templates=db).estimate_poses(inputs, labels, {1: (named,)})
    assert found.obj_id == HOLED


def test_without_the_edges_the_depth_keeps_the_twin_without_the_hole(twins):
    # main's outcome, which the test above changes
    meshes, db = twins
    inputs, labels, _, _ = _frame(meshes, HOLED)
    off = PerceptionPipeline(templates=db, fit_params=replace(FitParams(),
                                                              lookalike_edge_min_z=0.0))
    assert off.estimate_poses(inputs, labels, {1: (PLAIN,)})[0].obj_id == PLAIN


def test_no_rim_on_the_image_leaves_the_plain_plate_to_the_depth(twins):
    # the twin's rim meets no image edge: the edges leave it open (a missing edge votes for
    # neither) and the depth keeps the plain plate
    meshes, db = twins
    inputs, labels, _, _ = _frame(meshes, PLAIN)
    for named in (PLAIN, HOLED):
        [found] = PerceptionPipeline(templates=db).estimate_poses(inputs, labels, {1: (named,)})
        assert found.obj_id == PLAIN


@pytest.mark.parametrize('depth_kind', ['smoothed', 'per_pixel'])
def test_the_twins_are_refined_before_the_depth_vote_on_per_pixel_depth_only(
        twins, monkeypatch, depth_kind):
    # the refinement aligns the twins' holes on the pixels that see through the part; a
    # stereo-like depth has filled them (FitParams.lookalike_refine, flat_parts.refine_twins)
    from tlessbot_ros.core.pose import LookalikeCheck

    meshes, db = twins
    inputs, labels, _, _ = _frame(meshes, HOLED, depth_kind=depth_kind)
    asked = []
    resolve = LookalikeCheck.resolve

    def spy(self, *args, refine=False, **kwargs):
        asked.append(refine if isinstance(refine, bool) else refine())
        return resolve(self, *args, refine=refine, **kwargs)

    monkeypatch.setattr(LookalikeCheck, 'resolve', spy)
    # neither the edges nor the flat check's aligned votes decide first: the depth check runs
    depth_only = replace(FitParams(), lookalike_edge_min_z=0.0,
                         flat=replace(FitParams().flat, align_min_z=1e6))
    PerceptionPipeline(templates=db, fit_params=depth_only).estimate_poses(
        inputs, labels, {1: (PLAIN,)})
    assert asked == [depth_kind == 'per_pixel']


def _shadow_across_the_twin_s_hole(inputs, T_true, kind: str):
    """``inputs`` with a cast shadow (the colour at 55 %) whose edge runs through the centre of
    the hole that only the HOLED twin has: a straight edge along the image rows, or the round
    rim of a tube's shadow (per-pixel g 4100 frame 9, docs/bench/edge-votes-polarity.md)."""
    K = SIDE.intrinsics.K
    centre, off = transform_points(T_true, np.array([[0.039, 0.025, 0.006],
                                                     [0.039, 0.031, 0.006]]))
    u, v = (K @ (centre / centre[2]))[:2]
    radius = 2.0 * np.linalg.norm((K @ (off / off[2]))[:2] - (u, v))   # 4 hole widths
    rgb = inputs['side'].rgb.astype(np.float32)
    rows, cols = np.mgrid[0:rgb.shape[0], 0:rgb.shape[1]]
    if kind == 'straight':
        shadow = rows < v
    else:
        shadow = np.hypot(cols - u + 0.7 * radius, rows - v + 0.7 * radius) < radius
    rgb[shadow] *= 0.55
    return {'side': replace(inputs['side'], rgb=rgb.astype(np.uint8))}


@pytest.mark.parametrize('kind', ['straight', 'round'])
@pytest.mark.parametrize('named', [PLAIN, HOLED])
def test_a_shadow_s_edge_where_the_twin_s_hole_would_be_does_not_name_it(twins, kind, named):
    # where the twin's hole would be, the image shows the plate's face (lit or shadowed), so
    # its rims vote for neither twin (FlatParams.edge_hole_contrast); without that test the
    # shadow's edge on the rim names the twin
    meshes, db = twins
    inputs, labels, T_true, _ = _frame(meshes, PLAIN)
    views = _shadow_across_the_twin_s_hole(inputs, T_true, kind)
    [found] = PerceptionPipeline(templates=db).estimate_poses(views, labels, {1: (named,)})
    assert found.obj_id == PLAIN
    blind = replace(FitParams(), flat=replace(FitParams().flat, edge_hole_contrast=0.0))
    off = PerceptionPipeline(templates=db, fit_params=blind)
    assert off.estimate_poses(views, labels, {1: (named,)})[0].obj_id == HOLED


@pytest.mark.parametrize('contrast', [-1.0, -12.0])
def test_a_negative_hole_contrast_is_refused(contrast):
    from tlessbot_ros.core.pose.flat import FlatParams

    with pytest.raises(ValueError, match='edge_hole_contrast'):
        FlatParams(edge_hole_contrast=contrast)
    assert FlatParams(edge_hole_contrast=0.0).edge_hole_contrast == 0.0


def _votes_at_the_true_pose(twins, shown: int, *, shut_hole_votes: bool):
    """(PLAIN over HOLED, HOLED over PLAIN): the edge votes of both twins drawn at the true
    pose of part ``shown`` on its shaded side view."""
    from tlessbot_ros.core.common import raycasting_scene
    from tlessbot_ros.core.pose.flat import FlatParams, ViewEvidence
    from tlessbot_ros.core.pose.image_edges import candidate_edge_votes, flat_edge_settings

    meshes, db = twins
    inputs, labels, T_true, _ = _frame(meshes, shown)
    view = ViewEvidence(inputs['side'].rgb, labels['side'] > 0, SIDE.intrinsics, np.eye(4))
    candidates = [(raycasting_scene(*meshes[k]), T_true) for k in (PLAIN, HOLED)]
    points_o = np.concatenate([db[k].model_points for k in (PLAIN, HOLED)]).astype(np.float64)
    votes = candidate_edge_votes(candidates, points_o, [view], shut_hole_votes=shut_hole_votes,
                                 **flat_edge_settings(FlatParams()))   # type: ignore[arg-type]
    return int(votes[0, 1]), int(votes[1, 0])


def test_a_twin_s_hole_that_the_image_shows_shut_votes_against_it(twins):
    # the plain plate: the twin's rims meet no edge (a missing edge votes for neither), but
    # where the twin has its hole the image shows the face: those pixels vote for the plain one
    from tlessbot_ros.core.pose.lookalike import clear_margin

    assert _votes_at_the_true_pose(twins, PLAIN, shut_hole_votes=False) == (0, 0)
    plain, holed = _votes_at_the_true_pose(twins, PLAIN, shut_hole_votes=True)
    assert holed == 0 and clear_margin(plain, holed, FitParams().lookalike_edge_min_z)


def test_a_hole_the_image_shows_open_votes_for_no_twin_by_its_colour(twins):
    # the holed plate: its hole shows the table, so only its rims vote, as without the rule
    assert _votes_at_the_true_pose(twins, HOLED, shut_hole_votes=True) == \
        _votes_at_the_true_pose(twins, HOLED, shut_hole_votes=False)


@pytest.mark.parametrize('yaw_deg', [0.0, 40.0])
def test_the_plain_plate_named_as_its_holed_twin_is_renamed_on_the_image(twins, yaw_deg):
    # neither the depth's look-alike check nor the aligned votes may decide: the image's shut
    # hole alone names the plain plate; without the rule the classifier's twin stays
    meshes, db = twins
    inputs, labels, _, _ = _frame(meshes, PLAIN, yaw_deg=yaw_deg)
    image_only = replace(FitParams(), lookalike_min_z=1e6,
                         flat=replace(FitParams().flat, align_min_z=1e6))
    for rule, named in ((True, PLAIN), (False, HOLED)):
        params = replace(image_only, lookalike_shut_holes=rule)
        [found] = PerceptionPipeline(templates=db, fit_params=params).estimate_poses(
            inputs, labels, {1: (HOLED,)})
        assert found.obj_id == named
