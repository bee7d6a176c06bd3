"""Two fits of one class that fill the same space are one part fitted twice: the worse is a
fragment of the better, and its region joins it (issue 41, core/same_part.py)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from side_scene import SIDE, TABLE

from tlessbot_ros.core.common import MeshRenderer, make_transform, rotation_about_axis
from tlessbot_ros.core.fragments import FragmentFilter
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.one_part import join_pieces
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import PoseCandidate, PoseEstimator, build_database
from tlessbot_ros.core.same_part import same_part_test, shared_share

PLATE = (0.07, 0.048, 0.006)   # a plate 70 x 48 x 6 mm, diameter 85 mm


@pytest.fixture(scope='module')
def plate():
    """The plate's posed surface samples and normals at the origin, and their spacing."""
    box = trimesh.creation.box(extents=PLATE)
    points, faces = trimesh.sample.sample_surface_even(box, 3000, seed=1)
    normals = np.asarray(box.face_normals[faces])
    spacing = float(np.median(np.linalg.norm(np.diff(np.sort(points, axis=0), axis=0), axis=1)))
    return np.asarray(points), normals, max(spacing, 0.001)


def test_two_fits_of_one_plate_half_a_diameter_apart_share_its_space(plate):
    """The plate fitted twice, 0.55 diameters apart (beyond the centre test's 0.5): each has
    over a quarter of its samples in the other; side by side or stacked face to face, two
    plates share almost nothing (touching faces look opposite ways)."""
    points, normals, spacing = plate
    shift = 0.55 * np.linalg.norm(PLATE)
    assert shared_share(points, normals, points + [shift, 0, 0], normals, spacing) > 0.3
    beside = points + [0, PLATE[1] + 0.0005, 0]
    stacked = points + [0, 0, PLATE[2]]
    assert shared_share(points, normals, beside, normals, spacing) < 0.05
    assert shared_share(points, normals, stacked, normals, spacing) < 0.05
    assert shared_share(points, normals, points + [0.001, 0, 0], normals, spacing) > 0.8


@pytest.fixture(scope='module')
def estimator():
    box = trimesh.creation.box(bounds=np.array(((-0.035, -0.024, 0), (0.035, 0.024, 0.006))))
    db = build_database([(1, np.asarray(box.vertices), np.asarray(box.faces, np.int64),
                          [(np.eye(4), 1.0)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    return PoseEstimator(db)


def _job(instance, x_m, fitness, obj_id=1, yaw_deg=0.0):
    """A detection of the plate fitted at (x, 0) on the table, in the side view."""
    T_world = make_transform(rotation_about_axis([0, 0, 1], np.radians(yaw_deg)), [x_m, 0, 0])
    T = np.linalg.inv(SIDE.T_world_camera) @ T_world
    detection = Detection(instance, obj_id, 'side', (0, 0, 1, 1))
    detection.pose = PoseCandidate(T, fitness, 0.001, 1.0, 'table')
    return PartJob(detection, np.zeros((40, 3)), (obj_id,), SIDE.T_world_camera)


def test_same_part_test_joins_two_fits_of_one_class_that_overlap(estimator):
    shift = 0.55 * 0.085
    a, b, far = _job(1, 0.0, 0.9), _job(2, shift, 0.8), _job(3, 0.09, 0.8)
    other_class = _job(4, shift, 0.8, obj_id=2)
    same = same_part_test(0.3, estimator, [a, b, far, other_class])
    assert same is not None
    assert same(a.detection, b.detection) and same(b.detection, a.detection)
    assert not same(a.detection, far.detection)         # side by side: two parts
    assert not same(a.detection, other_class.detection)  # another class: not asked
    assert same_part_test(0.0, estimator, [a, b]) is None   # off


def test_the_worse_of_two_fits_of_one_part_is_dropped_and_its_region_joins():
    """Centres 0.6 diameters apart, neither fit explaining the other: both kept with no
    ``same`` (main's filter); with it, the worse is a fragment and its region joins the
    better's, so the part has one region and one box."""
    def run(same):
        a, b = Detection(1, 1, 'side', (10, 10, 5, 10)), Detection(2, 1, 'side', (15, 10, 5, 10))
        published: list[Detection] = []
        arbiter = FragmentFilter([(a, np.zeros(3), 'world', 900, 0.08),
                                  (b, np.array([0.048, 0, 0]), 'world', 800, 0.08)],
                                 published.append, overlap=0.5, same=same)
        arbiter.fitted(a, np.zeros(3), 0.08, 0.9)
        arbiter.fitted(b, np.array([0.048, 0, 0]), 0.08, 0.8)
        labels = {'side': np.zeros((40, 40), np.uint16)}
        labels['side'][10:20, 10:15], labels['side'][10:20, 15:20] = 1, 2
        kept = join_pieces(arbiter, [a, b], labels)
        return [d.instance_id for d in published], [d.instance_id for d in kept], labels, a
    published, kept, labels, _ = run(None)
    assert published == [1, 2] and kept == [1, 2]
    published, kept, labels, a = run(lambda x, y: True)
    assert published == [1] and kept == [1]
    assert set(np.unique(labels['side'])) == {0, 1} and a.box == (10, 10, 10, 10)


def test_same_part_share_is_a_share():
    assert FitParams().same_part_share == 0.3
    with pytest.raises(ValueError, match='same_part_share must be in 0..1'):
        FitParams(same_part_share=1.5)


def test_a_strip_cut_in_two_halves_is_one_part_by_the_space_its_fits_share():
    """A strip 90 x 16 x 4 mm whose region is cut at its middle column, with the joint refit
    off (piece_union.py): each half is fitted as the whole strip over itself, two parts on
    main's code; the two fits share the strip's space, so they are one part with one region
    (the worse half joins the better)."""
    box = trimesh.creation.box(bounds=np.array(((-0.045, -0.008, 0), (0.045, 0.008, 0.004))))
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces, np.int64)
    flipped = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi), [0, 0, 0.004])
    db = build_database([(1, vertices, faces, [(np.eye(4), 0.5), (flipped, 0.5)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    T_true = make_transform(rotation_about_axis([0, 0, 1], np.radians(60)), [0.004, -0.006, 0])
    renderer = MeshRenderer()
    renderer.add_mesh(*TABLE)
    renderer.add_mesh(vertices, faces, T_true)
    view = renderer.render(SIDE.intrinsics, SIDE.T_world_camera)
    labels = (view.instance >= 1).astype(np.uint16)
    labels[:, int(np.median(np.nonzero(labels)[1])):] *= 2
    rgb = np.full(labels.shape + (3,), 120, np.uint8)
    rgb[labels > 0] = (70, 100, 190)
    noise = np.random.default_rng(1).normal(0.0, 0.0005, labels.shape)
    depth = np.where(view.depth_m > 0, view.depth_m + noise, 0).astype(np.float32)
    views = {'side': ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}

    def found(image, **fit):
        pipeline = PerceptionPipeline(templates=db, fit_params=FitParams(**fit))
        return pipeline.estimate_poses(views, image, {1: (1,), 2: (1,)})
    off = {'side': labels.copy()}
    assert len(found(off, join_refit_cover=0.0, same_part_share=0.0)) == 2
    joined = {'side': labels.copy()}
    kept = found(joined, join_refit_cover=0.0)
    assert len(kept) == 1 and kept[0].pose is not None
    assert np.array_equal(joined['side'] == kept[0].instance_id, labels > 0)
