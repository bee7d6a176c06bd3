"""Two touching pieces of one part that neither piece's fit explains are one part when one fit
of both explains each (issue 41, core/piece_union.py)."""
from __future__ import annotations

from itertools import permutations

import numpy as np
import pytest
import trimesh
from side_scene import SIDE, TABLE

from tlessbot_ros.core.common import MeshRenderer, make_transform, rotation_about_axis
from tlessbot_ros.core.fragments import FragmentFilter
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.piece_union import regions_touch
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import build_database

YAW = rotation_about_axis([0, 0, 1], np.radians(60))
PLACE = np.array([0.004, -0.006, 0.0])


@pytest.fixture(scope='module')
def strip():
    """A strip 90 x 16 x 4 mm lying on either face: (vertices m, faces, template database)."""
    box = trimesh.creation.box(bounds=np.array(((-0.045, -0.008, 0), (0.045, 0.008, 0.004))))
    vertices, faces = np.asarray(box.vertices), np.asarray(box.faces, np.int64)
    flipped = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi), [0, 0, 0.004])
    db = build_database([(1, vertices, faces, [(np.eye(4), 0.5), (flipped, 0.5)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    return vertices, faces, db


def _side_view(vertices, faces, placements):
    """The side camera's view of the strip at each placement (T_world_object) on the table:
    (views, labels (one instance per strip, uint16))."""
    renderer = MeshRenderer()
    renderer.add_mesh(*TABLE)
    for T in placements:
        renderer.add_mesh(vertices, faces, T)
    view = renderer.render(SIDE.intrinsics, SIDE.T_world_camera)
    labels = np.where(view.instance >= 1, view.instance, 0).astype(np.uint16)
    rgb = np.full(labels.shape + (3,), 120, np.uint8)
    rgb[labels > 0] = (70, 100, 190)
    noise = np.random.default_rng(1).normal(0.0, 0.0005, labels.shape)
    depth = np.where(view.depth_m > 0, view.depth_m + noise, 0).astype(np.float32)
    return {'side': ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}, labels


def _found(db, views, labels, **fit):
    pipeline = PerceptionPipeline(templates=db, fit_params=FitParams(**fit))
    return pipeline.estimate_poses(views, labels, {1: (1,), 2: (1,)})


def test_a_strip_cut_in_two_halves_is_one_part_with_one_fit(strip):
    """Each half of the strip fits the whole strip over itself (neither explains the other:
    two parts on main's code); one fit of both halves explains each: one part, one region."""
    vertices, faces, db = strip
    T_true = make_transform(YAW, PLACE)
    views, labels = _side_view(vertices, faces, [T_true])
    columns = np.nonzero(labels)[1]
    labels[:, int(np.median(columns)):] *= 2
    split = {'side': labels.copy()}
    # the rule off (and same_part.py's, which joins these halves on its own)
    assert len(_found(db, views, split, join_refit_cover=0.0, same_part_share=0.0)) == 2
    joined = {'side': labels.copy()}
    found = _found(db, views, joined)
    assert len(found) == 1 and found[0].pose is not None
    kept = found[0].instance_id
    assert np.array_equal(joined['side'] == kept, labels > 0)
    T_world = SIDE.T_world_camera @ found[0].pose.T_camera_object
    assert np.linalg.norm(T_world[:2, 3] - T_true[:2, 3]) < 0.005


def test_two_strips_side_by_side_stay_two_regions(strip):
    """Two strips touching along their long sides: one fit covers one of them, not both."""
    vertices, faces, db = strip
    placements = [make_transform(YAW, YAW @ [0, side * 0.0085, 0] + PLACE) for side in (-1, 1)]
    views, labels = _side_view(vertices, faces, placements)
    assert regions_touch(labels, 1, 2, 0)
    two = {'side': labels.copy()}
    _found(db, views, two)
    assert np.array_equal(two['side'], labels)


def test_regions_touch_within_the_gap():
    image = np.zeros((5, 12), np.uint16)
    image[1:4, 1:4], image[1:4, 7:10] = 1, 2          # three empty columns between them
    assert not regions_touch(image, 1, 2, 2)
    assert regions_touch(image, 1, 2, 3)
    assert not regions_touch(image, 1, 3, 5)           # no instance 3


class _Detection:
    def __init__(self, instance_id):
        self.instance_id = instance_id


def test_a_piece_joins_only_a_keeper_not_yet_published():
    """``joins`` is asked of a worse neighbour neither fit explains, while its keeper waits;
    a keeper waits for its neighbours' neighbours too (main's code: handed to ``publish``
    while its piece waited for a third part, so the piece stayed a part of its own)."""
    a, b = _Detection(1), _Detection(2)
    asked, published = [], []

    def joins(keeper, piece):
        asked.append((keeper, piece))
        return True
    arbiter = FragmentFilter([(a, np.zeros(3), 'world', 500, 0.09),
                              (b, np.array([0.06, 0, 0]), 'world', 400, 0.09)],
                             published.append, overlap=0.5, explains=lambda x, y: False,
                             joins=joins)
    arbiter.fitted(b, np.array([0.06, 0, 0]), 0.09, 0.8)
    arbiter.fitted(a, np.zeros(3), 0.09, 0.9)
    assert published == [a] and arbiter.dropped == [b] and arbiter.kept_by == {id(b): a}
    assert asked == [(a, b)]
    c, d, e = _Detection(3), _Detection(4), _Detection(5)
    published.clear()
    later = FragmentFilter([(c, np.zeros(3), 'world', 500, 0.09),
                            (d, np.array([0.06, 0, 0]), 'world', 400, 0.09),
                            (e, np.array([0.13, 0, 0]), 'world', 400, 0.09)],
                           published.append, overlap=0.5, explains=lambda x, y: False,
                           joins=joins)
    later.fitted(c, np.zeros(3), 0.09, 0.9)
    later.fitted(d, np.array([0.06, 0, 0]), 0.09, 0.8)   # d waits for e, so c waits for d
    assert published == []
    later.fitted(e, np.array([0.13, 0, 0]), 0.09, 0.7)
    assert later.kept_by.get(id(d)) is c


def test_touching_pieces_are_asked_whatever_their_centroids_distance():
    """Two halves whose ROI centroids lie farther apart than half their summed diameters (one
    half with a table piece attached) are neighbours when their regions touch, so ``joins``
    is asked; pieces that do not touch stay apart (main's code: never asked)."""
    a, b, c = _Detection(1), _Detection(2), _Detection(3)
    asked, published = [], []

    def joins(keeper, piece):
        asked.append((keeper.instance_id, piece.instance_id))
        return True
    arbiter = FragmentFilter([(a, np.zeros(3), 'world', 500, 0.09),
                              (b, np.array([0.10, 0, 0]), 'world', 400, 0.09),
                              (c, np.array([-0.10, 0, 0]), 'world', 400, 0.09)],
                             published.append, overlap=0.5, explains=lambda x, y: False,
                             joins=joins, touching=lambda x, y: {x, y} == {a, b})
    arbiter.fitted(b, np.array([0.03, 0, 0]), 0.09, 0.8)
    arbiter.fitted(c, np.array([-0.10, 0, 0]), 0.09, 0.8)
    arbiter.fitted(a, np.zeros(3), 0.09, 0.9)
    assert asked == [(1, 2)]
    assert published == [c, a] and arbiter.dropped == [b] and arbiter.kept_by == {id(b): a}


def test_a_piece_left_unknown_joins_the_touching_part_whose_fit_of_both_explains_it():
    """A piece with no pose (named unknown) touching a fitted one: one fit of both explains
    each, so the piece joins it (main's code: kept as an unknown box); a piece that touches
    nothing, or one the joint fit does not explain, stays."""
    a, b, c, d = _Detection(1), _Detection(2), _Detection(3), _Detection(4)
    published = []
    touching = {frozenset((1, 2)), frozenset((1, 3))}
    arbiter = FragmentFilter([(a, np.zeros(3), 'world', 900, 0.09),
                              (b, np.array([0.02, 0, 0]), 'world', 300, 0.09),
                              (c, np.array([-0.02, 0, 0]), 'world', 300, 0.09),
                              (d, np.array([0.0, 0.03, 0]), 'world', 300, 0.09)],
                             published.append, overlap=0.5, explains=lambda x, y: False,
                             joins=lambda keeper, piece: piece is b,
                             touching=lambda x, y: frozenset((x.instance_id, y.instance_id))
                             in touching)
    for piece in (b, c, d):
        arbiter.fitted(piece, None, 0.0, -np.inf)
    arbiter.fitted(a, np.zeros(3), 0.09, 0.9)
    assert sorted(p.instance_id for p in published) == [1, 3, 4]
    assert arbiter.dropped == [b] and arbiter.kept_by == {id(b): a}


def test_two_touching_unknown_pieces_are_asked_once_the_larger_keeping():
    a, b = _Detection(1), _Detection(2)
    asked, published = [], []

    def joins(keeper, piece):
        asked.append((keeper.instance_id, piece.instance_id))
        return True
    arbiter = FragmentFilter([(a, np.zeros(3), 'world', 300, 0.09),
                              (b, np.array([0.10, 0, 0]), 'world', 600, 0.09)],
                             published.append, overlap=0.5, explains=lambda x, y: False,
                             joins=joins, touching=lambda x, y: True)
    arbiter.fitted(a, None, 0.0, -np.inf)
    arbiter.fitted(b, None, 0.0, -np.inf)
    assert asked == [(2, 1)] and published == [b] and arbiter.kept_by == {id(a): b}



def test_a_join_does_not_depend_on_when_a_third_part_touching_the_piece_is_fitted():
    """Two halves of one part (1, 2; one fit of both explains each) and a third part (3)
    touching the smaller half only: in every completion order the half joins the larger one
    and the third part goes out alone (main's code: when 1 and 2 were fitted before 3, 1 was
    handed to ``publish`` while 2 waited for 3, and 2 stayed a part of its own)."""
    fits = {1: (np.zeros(3), 0.9), 2: (np.array([0.12, 0, 0]), 0.8),
            3: (np.array([0.24, 0, 0]), 0.85)}
    for order in permutations(fits):
        d = {i: _Detection(i) for i in fits}
        published = []
        arbiter = FragmentFilter(
            [(d[i], fits[i][0], 'world', points, 0.09) for i, points in ((1, 600), (2, 300),
                                                                         (3, 500))],
            published.append, overlap=0.5, explains=lambda x, y: False,
            joins=lambda keeper, piece: {keeper.instance_id, piece.instance_id} == {1, 2},
            touching=lambda x, y: {x.instance_id, y.instance_id} in ({1, 2}, {2, 3}))
        for i in order:
            arbiter.fitted(d[i], fits[i][0], 0.09, fits[i][1])
        assert sorted(p.instance_id for p in published) == [1, 3], order
        assert arbiter.dropped == [d[2]] and arbiter.kept_by == {id(d[2]): d[1]}, order
