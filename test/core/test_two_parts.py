"""Two parts found as one region are two parts after the fit (issue 41, core/two_parts.py): the
connected piece of the region's depth that the first fit leaves unexplained is divided off,
fitted, and kept as a part of its own; a region its fit explains badly is refitted on its
halves first (core/refit_halves.py)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from tlessbot_ros.core.common import (
    MeshRenderer,
    default_rig,
    make_transform,
    mask_box,
    rotation_about_axis,
)
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import PoseCandidate, PoseParams, build_database, roi_cloud
from tlessbot_ros.core.refit_halves import explained_share, split_badly_explained, two_halves
from tlessbot_ros.core.two_parts import (
    MIN_COVERAGE,
    fill_one_space,
    reassigned,
    seen_share,
    unexplained_piece,
)

SIDE = default_rig()['side']
# the table path alone: the fallback stops at a wall-time budget, so its poses depend on the load
POSE = PoseParams(fallback=False)
TABLE = (np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], np.float64),
         np.array([[0, 1, 2], [0, 2, 3]]))


def _side_scene(parts, min_px: int):
    """Parts [(vertices, faces, T_world_object)] rendered on the table by the side camera:
    their masks (instances 1, 2, ..., each asserted over ``min_px`` pixels) and the side
    view (depth with 0.5 mm noise, blue parts on a grey table)."""
    renderer = MeshRenderer()
    renderer.add_mesh(*TABLE)
    for vertices, faces, T in parts:
        renderer.add_mesh(vertices, faces, T)
    view = renderer.render(SIDE.intrinsics, SIDE.T_world_camera)
    masks = [view.instance == k for k in range(1, len(parts) + 1)]
    assert all(m.sum() > min_px for m in masks)
    rng = np.random.default_rng(0)
    depth = (view.depth_m + rng.normal(0, 0.0005, masks[0].shape) * (view.depth_m > 0)).astype(
        np.float32)
    region = np.logical_or.reduce(masks)
    rgb = np.full((*region.shape, 3), 120, np.uint8)
    rgb[region] = (70, 100, 190)
    return masks, {'side': ViewInput(rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}


def _plate():
    """A plate 80 x 50 x 4 mm with a 15 mm notch at one corner (a flat part)."""
    trimesh = pytest.importorskip('trimesh')
    boxes = [((0, 0, 0), (0.08, 0.035, 0.004)), ((0, 0.035, 0), (0.065, 0.05, 0.004))]
    mesh = trimesh.util.concatenate([trimesh.creation.box(
        extents=np.subtract(hi, lo), transform=make_transform(np.eye(3), np.add(lo, hi) / 2))
        for lo, hi in boxes])
    return np.asarray(mesh.vertices), np.asarray(mesh.faces)


@pytest.fixture(scope='module')
def touching():
    """Two such plates lying on the table side by side, 1 mm apart (touching in the side
    camera's image), one region (label 1) holding both, as the localiser merges them; the
    database knows the plate (id 1, either face down) and a block (id 2)."""
    v, f = _plate()
    flipped = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi), [0, 0, 0.004])
    block = pytest.importorskip('trimesh').creation.box(extents=(0.03, 0.02, 0.02))
    db = build_database([(1, v, f, [(np.eye(4), 0.5), (flipped, 0.5)], None),
                         (2, np.asarray(block.vertices), np.asarray(block.faces),
                          [(make_transform(np.eye(3), [0, 0, 0.01]), 1.0)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    turn = rotation_about_axis([0, 0, 1], np.radians(25))
    poses = [make_transform(turn, [-0.06, 0.0, 0.0]),
             make_transform(turn, turn @ np.array([0.081, 0.0, 0.0]) + [-0.06, 0.0, 0.0])]
    (first, second), views = _side_scene([(v, f, T) for T in poses], 500)
    assert (np.roll(second, 1, 0) & first).any() or (np.roll(second, -1, 0) & first).any() or \
        (np.roll(second, 1, 1) & first).any() or (np.roll(second, -1, 1) & first).any()
    truth = [SIDE.T_camera_world @ T for T in poses]
    return db, views, (first | second).astype(np.uint16), first, second, truth


def test_two_touching_parts_in_one_region_are_found_as_two(touching):
    db, views, region, first, second, truth = touching
    labels = {'side': region.copy()}
    found = PerceptionPipeline(templates=db, pose=POSE).estimate_poses(views, labels, {1: (1,)})
    assert len(found) == 2 and all(d.obj_id == 1 and d.pose is not None for d in found)
    assert len(np.unique(labels['side'])) == 3          # the piece has a region of its own
    owners = []
    for part in (first, second):                         # each part has a region of its own
        shares = [np.mean(labels['side'][part] == d.instance_id) for d in found]
        owner = found[int(np.argmax(shares))]
        assert max(shares) > 0.8
        assert owner.box == mask_box(labels['side'] == owner.instance_id)
        owners.append(owner)
    assert owners[0] is not owners[1]
    # The rest's fit is right on every host. The piece (the second plate, a fifth of it left
    # in the rest's region by the first division) is fitted right on some hosts and turned
    # end for end on others (an AMD EPYC: the flat check's depth turn wins by 0.6 % of the
    # pixels, a near tie), so its pose is not asserted here (docs/bench/two-parts-host.md).
    # Refusing such small votes would not fix it: the piece's fit is already slid along its
    # neighbour, 45 mm off without the turn, and right turns on the bench win by nearly as little
    # (docs/bench/depth-turn-floor.md).
    gap = np.linalg.norm(owners[0].pose.T_camera_object[:3, 3] - truth[0][:3, 3])
    assert gap < 0.01


def test_split_off_can_be_turned_off(touching):
    db, views, region, *_ = touching
    pipeline = PerceptionPipeline(templates=db, pose=POSE,
                                  fit_params=FitParams(split_unexplained=False))
    assert len(pipeline.estimate_poses(views, {'side': region.copy()}, {1: (1,)})) == 1


def test_a_part_alone_leaves_at_most_a_rim(touching):
    """At its true pose a part leaves at most a sliver of its rim (the depth's noise at its
    edges): a few per cent of it, which the checks after the piece's fit reject."""
    db, views, region, first, second, truth = touching
    piece = unexplained_piece(first, views['side'].depth_m, SIDE.intrinsics.K, db[1], truth[0],
                              PerceptionPipeline(templates=db).pose_estimator.refiner,
                              inlier_m=0.003, min_points=30)
    assert piece is None or piece.sum() < 0.05 * first.sum()


def test_the_piece_is_the_part_the_fit_leaves_out(touching):
    db, views, region, first, second, truth = touching
    piece = unexplained_piece(region > 0, views['side'].depth_m, SIDE.intrinsics.K, db[1],
                              truth[0], PerceptionPipeline(templates=db).pose_estimator.refiner,
                              inlier_m=0.003, min_points=30)
    assert piece is not None
    assert np.mean(piece[second]) > 0.9 and np.mean(piece[first]) < 0.1
    assert not (piece & (region == 0)).any()



@pytest.fixture(scope='module')
def in_a_row():
    """A block, the plate and a block in a row on the table, 1 mm apart, one region holding
    all three; the database knows the plate (id 1) and the block (id 2)."""
    trimesh = pytest.importorskip('trimesh')
    v, f = _plate()
    block = trimesh.creation.box(extents=(0.03, 0.02, 0.02))
    bv, bf = np.asarray(block.vertices), np.asarray(block.faces)
    flipped = make_transform(rotation_about_axis([1.0, 0.0, 0.0], np.pi), [0, 0, 0.004])
    db = build_database([(1, v, f, [(np.eye(4), 0.5), (flipped, 0.5)], None),
                         (2, bv, bf, [(make_transform(np.eye(3), [0, 0, 0.01]), 1.0)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    turn = rotation_about_axis([0, 0, 1], np.radians(20))
    shift = np.array([-0.04, -0.01, 0.0])
    parts = [(bv, bf, make_transform(turn, turn @ np.array([-0.016, 0.02, 0.01]) + shift)),
             (v, f, make_transform(turn, shift)),
             (bv, bf, make_transform(turn, turn @ np.array([0.096, 0.015, 0.01]) + shift))]
    masks, views = _side_scene(parts, 300)
    region = np.logical_or.reduce(masks)
    return db, views, region.astype(np.uint16), masks, [SIDE.T_camera_world @ T
                                                        for *_, T in parts]


def test_three_parts_in_a_row_are_found_as_three(in_a_row):
    """The first fit lands on the plate in the middle and leaves both ends out; one end is
    divided off at a time, so the rest is divided again (issue 41: three parts in a row)."""
    db, views, region, masks, truth = in_a_row
    labels = {'side': region.copy()}
    found = PerceptionPipeline(templates=db, pose=POSE).estimate_poses(views, labels, {1: (1,)})
    assert len(found) == 3 and all(d.pose is not None for d in found)
    assert sorted(d.obj_id for d in found) == [1, 2, 2]
    for part, T in zip(masks, truth):
        gaps = [np.linalg.norm(d.pose.T_camera_object[:3, 3] - T[:3, 3]) for d in found]
        assert min(gaps) < 0.01
        owner = found[int(np.argmin(gaps))]
        assert np.mean(labels['side'][part] == owner.instance_id) > 0.8


def _fitted(instance: int, T_camera_object, labels, views) -> PartJob:
    """A plate (id 1) fitted at ``T_camera_object`` on region ``instance`` of ``labels``."""
    mask = labels == instance
    points = roi_cloud(views['side'].depth_m, mask, SIDE.intrinsics)
    detection = Detection(instance, 1, 'side', mask_box(mask))
    detection.pose = PoseCandidate(np.asarray(T_camera_object, np.float64), 1.0, 0.0)
    return PartJob(detection, points, (1,), SIDE.T_world_camera)


def test_pixels_without_depth_go_to_the_nearer_part(touching):
    """A patch of the second plate has no depth (a dark face, a thin rim) and lies in the
    first plate's region: it goes to the second, whose explained pixels surround it, not to
    the region it happened to be in."""
    db, views, region, first, second, truth = touching
    ys, xs = np.nonzero(second)
    patch = second & (np.abs(ys.mean() - np.arange(second.shape[0]))[:, None] < 4) & \
        (np.abs(xs.mean() - np.arange(second.shape[1]))[None, :] < 4)
    assert patch.sum() > 20
    depth = views['side'].depth_m.copy()
    depth[patch] = 0.0
    blind = {'side': ViewInput(views['side'].rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}
    labels = np.where(second & ~patch, 2, np.where(region > 0, 1, 0)).astype(np.uint16)
    pipeline = PerceptionPipeline(templates=db, pose=POSE)
    jobs = [_fitted(1, truth[0], labels, blind), _fitted(2, truth[1], labels, blind)]
    out = reassigned(pipeline, blind['side'], labels, *jobs)
    assert np.all(out[patch] == 2)
    assert np.mean(out[first] == 1) > 0.95


def test_a_piece_is_seen_where_it_is_fitted(touching):
    """The second plate fitted on its own region is seen there; a plate fitted over the first
    plate on a band of that plate's rim (what a fit a few millimetres off leaves
    unexplained) has its silhouette on the first plate's pixels: not seen, no part."""
    db, views, region, first, second, truth = touching
    pipeline = PerceptionPipeline(templates=db, pose=POSE)
    labels = np.where(second, 2, np.where(first, 1, 0)).astype(np.uint16)
    assert seen_share(pipeline, _fitted(2, truth[1], labels, views), views['side'],
                      labels) > 0.8
    rim = first & ~cv2.erode(first.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    banded = np.where(rim, 3, labels).astype(np.uint16)
    share = seen_share(pipeline, _fitted(3, truth[0], banded, views), views['side'], banded)
    assert share < MIN_COVERAGE


def test_the_last_labelling_gives_what_no_fit_explains_to_the_nearer_part(touching):
    """Once the fits are done, depth pixels that neither fit explains (here a patch of the
    second plate 2 cm off its surface, left in the first plate's region by the division) go
    to the part whose pixels surround them, so its box holds it; the fits' points stay."""
    db, views, region, first, second, truth = touching
    ys, xs = np.nonzero(second)
    patch = second & (np.abs(ys.mean() - np.arange(second.shape[0]))[:, None] < 4) & \
        (np.abs(xs.mean() - np.arange(second.shape[1]))[None, :] < 4)
    depth = views['side'].depth_m.copy()
    depth[patch] -= 0.02
    bumped = {'side': ViewInput(views['side'].rgb, depth, SIDE.intrinsics, SIDE.T_world_camera)}
    labels = np.where(second & ~patch, 2, np.where(region > 0, 1, 0)).astype(np.uint16)
    pipeline = PerceptionPipeline(templates=db, pose=POSE)
    jobs = [_fitted(1, truth[0], labels, bumped), _fitted(2, truth[1], labels, bumped)]
    assert np.all(reassigned(pipeline, bumped['side'], labels, *jobs)[patch] == 1)
    before = [len(job.points) for job in jobs]
    out = reassigned(pipeline, bumped['side'], labels, *jobs, final=True)
    assert np.all(out[patch] == 2)
    assert [len(job.points) for job in jobs] == before


@pytest.fixture(scope='module')
def two_blocks():
    """Two blocks 40 x 30 x 20 mm with a 10 mm step on top (no flat part), lying side by side
    on the table 1 mm apart, one region (label 1) holding both, as a pile merges them, and
    their true poses (camera frame); the database knows the block alone (id 2)."""
    trimesh = pytest.importorskip('trimesh')
    boxes = [((0, 0, 0), (0.04, 0.03, 0.01)), ((0, 0, 0.01), (0.025, 0.03, 0.02))]
    mesh = trimesh.util.concatenate([trimesh.creation.box(
        extents=np.subtract(hi, lo), transform=make_transform(np.eye(3), np.add(lo, hi) / 2))
        for lo, hi in boxes])
    v, f = np.asarray(mesh.vertices) - [0.02, 0.015, 0.0], np.asarray(mesh.faces)
    db = build_database([(2, v, f, [(np.eye(4), 1.0)], None)],
                        intrinsics=SIDE.intrinsics, T_world_camera=SIDE.T_world_camera)
    turn = rotation_about_axis([0, 0, 1], np.radians(25))
    poses = [make_transform(turn, [-0.03, 0.0, 0.0]),
             make_transform(turn, turn @ np.array([0.041, 0.0, 0.0]) + [-0.03, 0.0, 0.0])]
    (first, second), views = _side_scene([(v, f, T) for T in poses], 500)
    truth = [SIDE.T_camera_world @ T for T in poses]
    return db, views, (first | second).astype(np.uint16), first, second, truth


def test_two_thick_parts_in_one_region_are_divided_with_split_thick_parts(two_blocks):
    """Piles (issue 41): thick parts that touch are one region where no depth seam parts
    them; with ``split_thick_parts`` the division after the fit runs for them too."""
    db, views, region, first, second, _ = two_blocks
    off = PerceptionPipeline(templates=db, pose=POSE)
    assert off.fit_params.split_thick_parts is False
    assert len(off.estimate_poses(views, {'side': region.copy()}, {1: (2,)})) == 1
    labels = {'side': region.copy()}
    found = PerceptionPipeline(templates=db, pose=POSE,
                               fit_params=FitParams(split_thick_parts=True)).estimate_poses(
        views, labels, {1: (2,)})
    assert len(found) == 2 and all(d.obj_id == 2 and d.pose is not None for d in found)
    for part in (first, second):   # each block has a region of its own
        assert max(np.mean(labels['side'][part] == d.instance_id) for d in found) > 0.8


def test_a_piece_inside_the_rest_s_fit_is_no_part_of_its_own(two_blocks):
    """Two rigid parts cannot fill one space: a thick part's piece fitted inside the rest's
    fitted model is the rest's part, left out by a fit a little off; a neighbour beside it
    is not."""
    db = two_blocks[0]
    pipeline = PerceptionPipeline(templates=db, pose=POSE)
    T_world_camera = SIDE.T_world_camera

    def fitted(x_m: float) -> PartJob:
        T = SIDE.T_camera_world @ make_transform(np.eye(3), [x_m, 0.0, 0.0])
        detection = Detection(1, 2, 'side', (0, 0, 1, 1),
                              pose=PoseCandidate(T, 0.9, 0.001, 0.9, 'table'))
        return PartJob(detection, np.zeros((0, 3)), (2,), T_world_camera)

    assert fill_one_space(pipeline, fitted(0.0), fitted(0.006))
    assert not fill_one_space(pipeline, fitted(0.0), fitted(0.041))


# ------------------------------------ a fit between two parts: refitted on the region's halves
def _between(labels: np.ndarray, views, truth) -> PartJob:
    """The region fitted once as one block straddling the seam: halfway between the two."""
    mask = labels == 1
    T = truth[0].copy()
    T[:3, 3] = (truth[0][:3, 3] + truth[1][:3, 3]) / 2
    detection = Detection(1, 2, 'side', mask_box(mask), pose=PoseCandidate(T, 0.5, 0.002))
    return PartJob(detection, roi_cloud(views['side'].depth_m, mask, SIDE.intrinsics), (2,),
                   SIDE.T_world_camera)


def test_the_halves_are_the_two_parts(two_blocks):
    db, views, region, first, second, truth = two_blocks
    halves = two_halves(region > 0, views['side'].depth_m, SIDE.intrinsics.K,
                        SIDE.T_world_camera)
    assert halves is not None
    for half in halves:   # each half lies on one block
        assert max(np.mean(first[half]), np.mean(second[half])) > 0.9


def test_a_fit_between_two_parts_is_divided_into_both(two_blocks):
    """The fit between the blocks explains under half the region: refitted on its halves, the
    better half's block leaves the other out, which is divided off; each block ends with its
    own region and a pose on it. Off by default (and with ``split_thick_parts`` off, the
    division after the first fit never runs for two thick parts)."""
    db, views, region, first, second, truth = two_blocks
    labels = {'side': region.copy()}
    pipeline = PerceptionPipeline(templates=db, pose=POSE,
                                  fit_params=FitParams(split_refit_below=0.7))
    job = _between(labels['side'], views, truth)
    assert explained_share(pipeline, job) < 0.7
    off = PerceptionPipeline(templates=db, pose=POSE)
    assert split_badly_explained(off, _between(labels['side'], views, truth), views,
                                 {'side': region.copy()}) is None
    piece = split_badly_explained(pipeline, job, views, labels)
    assert piece is not None
    found = [job.detection, piece.detection]
    for part, T in zip((first, second), truth):
        gaps = [np.linalg.norm(d.pose.T_camera_object[:3, 3] - T[:3, 3]) for d in found]
        assert min(gaps) < 0.01
        owner = found[int(np.argmin(gaps))]
        assert np.mean(labels['side'][part] == owner.instance_id) > 0.8


def test_a_part_fitted_well_is_not_refitted(two_blocks):
    """A fit on one block alone explains its region: nothing is refitted or divided."""
    db, views, region, first, second, truth = two_blocks
    labels = {'side': first.astype(np.uint16)}
    pipeline = PerceptionPipeline(templates=db, pose=POSE,
                                  fit_params=FitParams(split_refit_below=0.7))
    mask = labels['side'] == 1
    detection = Detection(1, 2, 'side', mask_box(mask), pose=PoseCandidate(truth[0], 0.9, 0.001))
    job = PartJob(detection, roi_cloud(views['side'].depth_m, mask, SIDE.intrinsics), (2,),
                  SIDE.T_world_camera)
    assert explained_share(pipeline, job) >= 0.7
    assert split_badly_explained(pipeline, job, views, labels) is None
    assert np.array_equal(job.detection.pose.T_camera_object, truth[0])
