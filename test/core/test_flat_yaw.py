"""The yaw of a round flat part told by its holes: a disc with four small bolt holes, seen from
the side camera, is turned back to its true yaw within its quarter-turn period from a fit 7 to
40 degrees off; where the image shows no holes, the pose stays; plates and plain discs are not
searched."""
from __future__ import annotations

import numpy as np
import pytest
from side_scene import (
    HOLE_R,
    RADIUS,
    SIDE,
    THICK,
    holed_disc_database,
    holed_disc_mesh,
    holed_plate,
    side_scene,
    yaw_error_deg,
)

from tlessbot_ros.core.common import (
    make_transform,
    plane_of_frame,
    raycasting_scene,
    rotation_about_axis,
    sample_surface,
)
from tlessbot_ros.core.pose.database import ObjectTemplates
from tlessbot_ros.core.pose.flat import FlatParams, ViewEvidence


def _templates(vertices: np.ndarray, faces: np.ndarray, period: float) -> ObjectTemplates:
    """The fields the yaw search reads: samples, a listed yaw period resting on a face."""
    points, normals = sample_surface(vertices, faces, 4000, seed=0)
    return ObjectTemplates(
        obj_id=1, diameter_m=2 * RADIUS, voxel_size_m=0.002,
        model_points=points.astype(np.float32), model_normals=normals.astype(np.float32),
        stable_poses=np.eye(4)[None], stable_probabilities=np.ones(1),
        yaw_periods=np.zeros(1), listed_yaw_periods=np.array([period]))


@pytest.fixture(scope='module')
def holed_disc():
    vertices, faces = holed_disc_mesh()
    return vertices, faces, _templates(vertices, faces, np.pi / 2)


def _view(vertices, faces, yaw_deg: float, seed: int = 3):
    """The disc on the table at ``yaw_deg`` seen from the side: (evidence, T_camera_object)."""
    T_world = make_transform(rotation_about_axis([0, 0, 1], np.radians(yaw_deg)),
                             [0.004, -0.006, 0.0])
    rgb, depth, mask = side_scene(vertices, faces, T_world, noise_m=0.0005, seed=seed)
    evidence = [ViewEvidence(rgb, mask, SIDE.intrinsics, np.eye(4), depth,
                             plane_of_frame(SIDE.T_world_camera), None)]
    return evidence, np.linalg.inv(SIDE.T_world_camera) @ T_world


def test_the_disc_mesh_is_closed_and_has_its_holes():
    trimesh = pytest.importorskip('trimesh')
    vertices, faces = holed_disc_mesh()
    mesh = trimesh.Trimesh(vertices, faces, process=True)
    assert mesh.is_watertight
    plain = trimesh.Trimesh(*holed_disc_mesh(holes=0), process=True)
    hole_area = 4 * np.pi * HOLE_R ** 2 * THICK
    assert plain.volume - mesh.volume == pytest.approx(hole_area, rel=0.25)


@pytest.mark.parametrize('off_deg', [-11.0, 7.0, 40.0])
def test_a_disc_is_turned_to_the_yaw_its_holes_show(holed_disc, off_deg):
    # fitted 7 to 40 degrees off about its axis (the depth and the round outline hold no
    # yaw): the search over its quarter-turn period finds where its holes are
    from tlessbot_ros.core.pose.flat_yaw import hole_yaw

    vertices, faces, obj = holed_disc
    evidence, T_true = _view(vertices, faces, 23.0)
    T_fit = T_true @ make_transform(rotation_about_axis([0, 0, 1], np.radians(off_deg)),
                                    [0, 0, 0])
    assert yaw_error_deg(T_fit, T_true, 90.0) > 5.0
    T, turned = hole_yaw(obj, raycasting_scene(vertices, faces), T_fit, evidence, FlatParams())
    assert turned != 0.0
    assert yaw_error_deg(T, T_true, 90.0) < 2.0


def test_a_disc_whose_holes_the_image_does_not_show_keeps_its_pose(holed_disc):
    # the image of a disc without holes: every turn of the holed mesh explains it alike, no
    # turn wins the votes by a clear margin, and the fitted yaw stays
    from tlessbot_ros.core.pose.flat_yaw import hole_yaw

    vertices, faces, obj = holed_disc
    evidence, T_true = _view(*holed_disc_mesh(holes=0), 23.0)
    T_fit = T_true @ make_transform(rotation_about_axis([0, 0, 1], np.radians(20.0)),
                                    [0, 0, 0])
    T, turned = hole_yaw(obj, raycasting_scene(vertices, faces), T_fit, evidence, FlatParams())
    assert turned == 0.0 and np.array_equal(T, T_fit)


def test_only_round_parts_with_a_listed_period_are_searched(holed_disc):
    from tlessbot_ros.core.pose.flat_yaw import hole_yaw_period

    vertices, faces, obj = holed_disc
    assert hole_yaw_period(obj) == pytest.approx(np.pi / 2)
    assert hole_yaw_period(_templates(vertices, faces, 0.0)) == 0.0      # continuous
    plate = np.array([[x, y, z] for x in np.linspace(0, 0.06, 31)
                      for y in np.linspace(0, 0.04, 21) for z in (0.0, 0.004)])
    rectangle = _templates(vertices, faces, 2 * np.pi)
    rectangle = ObjectTemplates(**{**rectangle.__dict__, 'model_points': plate.astype(
        np.float32), '_cache': {}})
    assert hole_yaw_period(rectangle) == 0.0


def test_check_flat_leaves_a_disc_at_the_yaw_its_holes_show(holed_disc):
    # the whole check of a fitted flat part (check_flat): a disc fitted 7.5 degrees off, half
    # way between two of the aligned round's yaw turns (15 degrees apart), ends within 2
    # degrees of its true yaw; the silhouette's yaw check, blind to a round outline's yaw,
    # left it where the fit and the polish put it
    from types import SimpleNamespace

    from tlessbot_ros.core.common import depth_to_points
    from tlessbot_ros.core.flat_parts import check_flat
    from tlessbot_ros.core.frame import Detection, PartJob, ViewInput
    from tlessbot_ros.core.params import FitParams
    from tlessbot_ros.core.pose import PoseCandidate, PoseEstimator

    vertices, faces, _ = holed_disc
    db, T_world = holed_disc_database(vertices, faces)
    rgb, depth, mask = side_scene(vertices, faces, T_world, noise_m=0.0005, seed=3)
    points, _ = depth_to_points(depth, SIDE.intrinsics.K, mask=mask)
    T_true = np.linalg.inv(SIDE.T_world_camera) @ T_world
    T_fit = T_true @ make_transform(rotation_about_axis([0, 0, 1], np.radians(7.5)), [0, 0, 0])
    pipeline = SimpleNamespace(pose_estimator=PoseEstimator(db), fit_params=FitParams(),
                               table_frame=lambda name, view: view)   # the rig's table
    detection = Detection(1, 1, 'side', (0, 0, 1, 1), pose=PoseCandidate(
        T_camera_object=T_fit, fitness=1.0, inlier_rmse_m=0.001))
    job = PartJob(detection, points, (1,), SIDE.T_world_camera, ())
    views = {'side': ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}
    check_flat(pipeline, job, views, {'side': mask.astype(np.uint16)})
    assert detection.pose is not None
    assert yaw_error_deg(detection.pose.T_camera_object, T_true, 90.0) < 2.0


def test_a_disc_with_one_hole_is_searched_in_steps_its_hole_resolves():
    # one 3.8 mm hole 16 mm out: no symmetry (period 2π), and six coarse steps (60 degrees)
    # would leave the true yaw up to 30 degrees from the nearest, where the hole of the
    # rendering no longer overlaps the imaged one; the steps are as wide as the turn over
    # which the hole moves off itself (3.8 / 16 rad, some 14 degrees)
    from tlessbot_ros.core.pose.flat_yaw import feature_turn, hole_yaw

    vertices, faces = holed_disc_mesh(holes=1)
    obj = _templates(vertices, faces, 2 * np.pi)
    mesh = raycasting_scene(vertices, faces)
    assert 8.0 < np.degrees(feature_turn(obj, mesh, 2 * np.pi)) < 20.0
    evidence, T_true = _view(vertices, faces, -50.0, seed=4)
    T_fit = T_true @ make_transform(rotation_about_axis([0, 0, 1], np.radians(130.0)),
                                    [0, 0, 0])
    T, _ = hole_yaw(obj, mesh, T_fit, evidence, FlatParams())
    assert yaw_error_deg(T, T_true, 360.0) < 2.0


@pytest.mark.parametrize('off_deg', [-5.5, 4.5])
def test_a_plate_lying_a_few_degrees_off_is_turned_to_its_yaw(off_deg):
    # a rectangle's outline holds its yaw only to a few degrees (the silhouette's check
    # stops there); its edges and hole, scored by the aligned score, within a degree
    from tlessbot_ros.core.pose.flat_yaw import hole_yaw

    vertices, faces = holed_plate()
    obj = _templates(vertices, faces, 2 * np.pi)
    evidence, T_true = _view(vertices, faces, 23.0)
    T_fit = T_true @ make_transform(rotation_about_axis([0, 0, 1], np.radians(off_deg)),
                                    [0, 0, 0])
    normal_c = np.linalg.inv(SIDE.T_world_camera)[:3, 2]
    T, turned = hole_yaw(obj, raycasting_scene(vertices, faces), T_fit, evidence,
                         FlatParams(), normal_c)
    assert turned != 0.0 and yaw_error_deg(T, T_true, 360.0) < 1.0
    # standing on an edge, a turn about its thin axis would lift it off the table: not tried
    standing = np.linalg.inv(SIDE.T_world_camera) @ make_transform(
        rotation_about_axis([1.0, 0.0, 0.0], np.pi / 2), [0, 0, 0.02])
    T, turned = hole_yaw(obj, raycasting_scene(vertices, faces), standing, evidence,
                         FlatParams(), normal_c)
    assert turned == 0.0 and np.array_equal(T, standing)


def test_the_yaw_search_finds_the_pose_s_shift_on_the_grid_once(monkeypatch):
    # the fit's error in the table plane is shared by turns a few degrees apart: each view's
    # grid of shifts is searched once (for the pose), the turns' shifts climbed to from there
    from tlessbot_ros.core.pose import flat_align, flat_yaw

    grids: list[int] = []
    original = flat_align.shift_of

    def counted(view, k, tolerance_m, near=None):
        if near is None:
            grids.append(1)
            return original(view, k, tolerance_m)
        return original(view, k, tolerance_m, near)

    monkeypatch.setattr(flat_yaw, 'shift_of', counted)
    vertices, faces = holed_plate()
    obj = _templates(vertices, faces, 2 * np.pi)
    evidence, T_true = _view(vertices, faces, 23.0)
    T_fit = T_true @ make_transform(rotation_about_axis([0, 0, 1], np.radians(-5.5)),
                                    [0, 0, 0])
    normal_c = np.linalg.inv(SIDE.T_world_camera)[:3, 2]
    T, turned = flat_yaw.hole_yaw(obj, raycasting_scene(vertices, faces), T_fit, evidence,
                                  FlatParams(), normal_c)
    assert turned != 0.0 and yaw_error_deg(T, T_true, 360.0) < 1.0
    assert len(grids) == len(evidence)
