"""Touching parts told apart by depth: the hole-tolerant depth vote, range jumps, the depth
split of a blob and the fusion that keeps the side view's depth split."""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from tlessbot_ros.core.common import MeshRenderer, default_rig, make_transform
from tlessbot_ros.core.localise import (
    FusionParams,
    Segmentation,
    SegmentationParams,
    boxes_from_labels,
    fuse_views,
    lift_top_blobs,
    predict_side_regions,
    segment,
    split_touching,
)
from tlessbot_ros.core.localise.cues import range_jumps

W, H = 320, 240


def test_range_jumps_mark_steps_not_slopes() -> None:
    step = np.full((20, 40), 0.60, np.float32)
    step[:, 20:] = 0.65   # one surface 5 cm behind the other
    jumps = range_jumps(step, 0.02)
    assert jumps[:, 19:21].all() and jumps.sum() == 2 * 20
    ramp = np.tile(np.linspace(0.60, 0.70, 40, dtype=np.float32), (20, 1))   # 2.5 mm a pixel
    assert not range_jumps(ramp, 0.02).any()
    holed = step.copy()
    holed[:, 19:21] = 0.0   # holes are not jumps, and never marked
    assert not range_jumps(holed, 0.02).any()


def _top_view_of_box(hole_fraction: float):
    """Top view of a dark 120x80x30 mm box on a dark table, part depth mostly holes: rgb,
    depth_m, truth mask, camera."""
    cam = default_rig(W, H)['top']
    v = np.array([[x, y, z] for x in (-0.06, 0.06) for y in (-0.04, 0.04) for z in (0, 0.03)])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    renderer = MeshRenderer()
    renderer.add_mesh(v, f, make_transform(np.eye(3), [0.0, 0.0, 0.0]))
    res = renderer.render(cam.intrinsics, cam.T_world_camera)
    truth = res.instance == 0
    rays = np.linalg.inv(cam.intrinsics.K) @ np.vstack([
        np.mgrid[0:H, 0:W][::-1].reshape(2, -1), np.ones((1, H * W))])
    R, t = cam.T_world_camera[:3, :3], cam.T_world_camera[:3, 3]
    table_z = (-t[2] / (R[2] @ rays)).reshape(H, W)
    rng = np.random.default_rng(4)
    depth = np.where(truth, res.depth_m, table_z).astype(np.float32)
    depth += rng.normal(0, 0.001, depth.shape).astype(np.float32)
    depth[truth & (rng.random(depth.shape) < hole_fraction)] = np.nan
    rgb = np.where(truth[..., None], 34.0, 30.0) + rng.normal(0, 2.0, (H, W, 3))
    return np.clip(rgb, 0, 255).astype(np.uint8), depth, truth, cam


def _best_iou(labels: np.ndarray, truth: np.ndarray) -> float:
    ids = [i for i in np.unique(labels[truth]) if i]
    return max((float((truth & (labels == i)).sum() / (truth | (labels == i)).sum())
                for i in ids), default=0.0)


def test_depth_vote_finds_a_part_whose_depth_is_mostly_holes() -> None:
    # A dark part seen from afar returns depth in scattered pixels only.
    rgb, depth, truth, cam = _top_view_of_box(0.6)
    kwargs = dict(depth_m=depth, intrinsics=cam.intrinsics, T_world_camera=cam.T_world_camera)
    seg = segment(rgb, **kwargs)
    assert seg.count == 1
    assert _best_iou(seg.labels, truth) > 0.85
    # The median that counts holes as table height loses most of it.
    median = segment(rgb, params=SegmentationParams(depth_vote_valid=False), **kwargs)
    assert _best_iou(median.labels, truth) < 0.5


def _two_blocks(gap_height_m: float):
    """Two 60x40 px blocks 30 mm high side by side in a top view, one grey blob in colour,
    a 2 px seam between them at ``gap_height_m``: mask, rgb, height, depth, truth labels."""
    rng = np.random.default_rng(7)
    height = rng.normal(0.0, 0.0005, (H, W)).astype(np.float32)
    truth = np.zeros((H, W), np.int32)
    truth[100:140, 100:160] = 1
    truth[100:140, 162:222] = 2
    height[truth > 0] += 0.030
    height[100:140, 160:162] += np.float32(gap_height_m)
    mask = np.zeros((H, W), bool)
    mask[100:140, 100:222] = True
    rgb = np.full((H, W, 3), 150, np.uint8)
    rgb[mask] = 60
    depth = (1.0 - height).astype(np.float32)   # a camera 1 m above the table, looking down
    return mask, rgb, height, depth, truth


def test_touching_parts_are_split_where_the_table_shows_between_them() -> None:
    mask, rgb, height, depth, truth = _two_blocks(0.0)
    assert split_touching(mask, rgb).max() == 1   # one rectangle: no colour or shape cue
    labels = split_touching(mask, rgb, height_m=height, depth_m=depth)
    assert labels.max() == 2
    for k in (1, 2):
        assert _best_iou(labels, truth == k) > 0.9
    off = SegmentationParams(depth_split_jump=0.0)
    assert split_touching(mask, rgb, height_m=height, depth_m=depth, params=off).max() == 1


def test_a_groove_of_one_part_is_not_a_seam() -> None:
    # The groove breaks the surface (range jumps, low pixels) but shows no table.
    mask, rgb, height, depth, _ = _two_blocks(0.006)
    assert split_touching(mask, rgb, height_m=height, depth_m=depth).max() == 1


def _segmentation(labels: np.ndarray, groups: list[int],
                  thin: list[bool] | None = None) -> Segmentation:
    boxes, areas = boxes_from_labels(labels)
    return Segmentation(labels=labels.astype(np.uint16), boxes=boxes, areas=areas,
                        foreground=labels > 0, depth_groups=np.array(groups, np.int32),
                        thin=np.array(thin or [False] * len(groups), bool))


def test_fusion_keeps_the_side_views_depth_split_of_a_blob_the_top_saw_as_one() -> None:
    rig = default_rig(W, H)
    top = np.zeros((H, W), np.int32)
    top[100:130, 140:180] = 1
    predicted = predict_side_regions(lift_top_blobs(top, rig), rig) == 1
    ys, xs = np.nonzero(predicted)
    side = np.zeros((H, W), np.int32)
    side[predicted] = 1
    cut = int(np.percentile(xs, 70))   # the smaller piece: a part behind, seen from the side
    side[predicted & (np.arange(W)[None, :] >= cut)] = 2
    top_seg = _segmentation(top, [0])

    def fused(groups, **params):
        return fuse_views(top_seg, _segmentation(side, groups), rig=rig,
                          params=FusionParams(**params))

    result = fused([1, 2])
    assert len(result.instances) == 2
    first, second = result.instances
    assert first.views == ('top', 'side') and second.views == ('side',)
    assert np.array_equal(result.labels['side'] == 1, side == 1)   # the larger overlap
    assert np.array_equal(result.labels['side'] == second.instance_id, side == 2)
    # Pieces of another kind of split (colour, distance cores) are the top blob's, as before,
    # and so are depth pieces when the option is off.
    assert len(fused([0, 0]).instances) == 1
    assert len(fused([1, 2], keep_depth_splits=False).instances) == 1


def _one_top_blob_two_side_pieces(rig, top_ids, cut=70):
    """A top blob (or two, ``top_ids``: left and right half) and the side view's region of
    it cut in two instances at ``cut`` % of its width."""
    top = np.zeros((H, W), np.int32)
    top[100:130, 140:180] = 1
    top[100:130, 160:180] = top_ids[1]
    predicted = predict_side_regions(lift_top_blobs(top > 0, rig), rig) == 1
    ys, xs = np.nonzero(predicted)
    side = np.zeros((H, W), np.int32)
    side[predicted] = 1
    side[predicted & (np.arange(W)[None, :] >= int(np.percentile(xs, cut)))] = 2
    return top, side


def test_fusion_keeps_a_thin_part_apart_from_a_tall_one_the_top_saw_as_one() -> None:
    # A plate lying against a taller part: the top view, farther away, sees one blob.
    rig = default_rig(W, H)
    top, side = _one_top_blob_two_side_pieces(rig, (1, 1))

    def fused(thin, **params):
        return fuse_views(_segmentation(top, [0]), _segmentation(side, [0, 0], thin),
                          rig=rig, params=FusionParams(**params))

    assert len(fused([True, False]).instances) == 2
    assert len(fused([True, True]).instances) == 1      # two pieces of one thin part
    assert len(fused([False, False]).instances) == 1    # cores of one part: the top's call
    assert len(fused([True, False], keep_thin_beside_tall=False).instances) == 1


def test_a_side_piece_the_top_gives_no_part_joins_the_part_it_overlaps_most() -> None:
    # Two top blobs over one side blob that the side depth divided so that both predictions
    # fall mostly on its larger piece: the smaller piece is a fragment, not a third part.
    rig = default_rig(W, H)
    top, side = _one_top_blob_two_side_pieces(rig, (1, 2), cut=90)
    result = fuse_views(_segmentation(top, [0, 0]), _segmentation(side, [1, 2]), rig=rig)
    side_ids = set(np.unique(result.labels['side'])) - {0}
    assert side_ids <= {1, 2} and len(side_ids) == 2


def test_pieces_meeting_by_a_neck_are_apart_but_tied() -> None:
    # Two solid pieces whose only contact is a neck narrower than the seam test can read
    # (a rod entering a handle, two parts meeting at a corner): kept apart in the side
    # segmentation, tied so the fusion lets the top view decide.
    from tlessbot_ros.core.localise.blob_split import depth_pieces
    from tlessbot_ros.core.localise.cues import Surfaces

    blob = np.zeros((40, 70), bool)
    blob[10:30, 5:30] = blob[10:30, 40:65] = True
    solid = blob.copy()
    blob[19:21, 30:40] = True                  # the neck, 2 px wide, lower than the pieces
    surfaces = Surfaces(solid, np.zeros_like(blob), np.where(blob, 0.7, 0.0).astype(np.float32))
    params = SegmentationParams(depth_split_min_px=50)
    pieces, ties = depth_pieces(blob, surfaces, None, params)
    assert len(pieces) == 2 and ties == [0, 0]
    blob[15:25, 30:40] = True                  # a wide contact showing no table: one part
    assert len(depth_pieces(blob, surfaces, None, params)[0]) == 1


def _three_side_instances(rig):
    """Two top blobs side by side, and the side view's region of them cut in three
    instances: the first under the first blob's prediction, the second and third under the
    second's (the second reaching a little under the first's)."""
    top = np.zeros((H, W), np.int32)
    top[100:130, 140:160] = 1
    top[100:130, 160:190] = 2
    pred = predict_side_regions(lift_top_blobs(top, rig), rig)
    cols = np.arange(W)[None, :]
    end_first = int(np.nonzero((pred == 1).any(axis=0))[0].max())
    xs_second = np.nonzero((pred == 2).any(axis=0))[0]
    third_from = int(np.percentile(xs_second[xs_second > end_first], 40))
    # one side blob: the predictions, and the few columns between them the top left out
    region = cv2.morphologyEx((pred > 0).astype(np.uint8), cv2.MORPH_CLOSE,
                              np.ones((1, 9), np.uint8)) > 0
    side = np.zeros((H, W), np.int32)
    side[region] = 1
    side[region & (cols > end_first - 3)] = 2
    side[region & (cols >= third_from)] = 3
    return top, side, pred


def test_side_instances_the_top_gives_two_parts_stay_apart_in_a_depth_piece() -> None:
    # The side depth divides the blob in two pieces: instances 1 + 2 (one depth group) and
    # 3. The top view's predictions give instance 1 to its first blob, 2 and 3 to its second,
    # which overlaps instance 3 most: before, instance 2 went with instance 1.
    rig = default_rig(W, H)
    top, side, pred = _three_side_instances(rig)
    share = [np.count_nonzero((side == 2) & (pred == k)) for k in (1, 2)]
    assert share[1] > share[0] > 0   # the second instance is mostly the second blob's
    whole = 0.5 * min(np.count_nonzero(side == k) for k in (1, 2, 3))

    def fused(**params) -> list[int]:
        top_seg, side_seg = (replace(_segmentation(labels, groups),
                                     whole_parts=np.array([[0.1, whole, 1000.0]]))
                             for labels, groups in ((top, [0, 0]), (side, [1, 1, 2])))
        labels = fuse_views(top_seg, side_seg, rig=rig, params=FusionParams(**params)
                            ).labels['side']
        return [int(np.bincount(labels[side == k]).argmax()) for k in (1, 2, 3)]

    first, second, third = fused()
    assert len({first, second, third}) == 3 and min(first, second, third) > 0
    first, second, third = fused(whole_pieces_apart=False)   # a fragment of the second
    assert first != second == third
    first, second, third = fused(keep_apart_by_prediction=False)   # as before
    assert first == second != third
