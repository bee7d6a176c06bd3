"""Two side blobs that one top blob predicts: apart where the table shows between them
(:mod:`tlessbot_ros.core.localise.table_gap`), one part where something else may join them."""
from __future__ import annotations

import cv2
import numpy as np

from tlessbot_ros.core.common import MeshRenderer, default_rig
from tlessbot_ros.core.localise import (
    FusionParams,
    Segmentation,
    boxes_from_labels,
    fuse_views,
    lift_top_blobs,
    predict_side_regions,
    segment,
)

W, H = 320, 240


def _one_top_blob_two_side_blobs(rig):
    """A top blob, and its predicted side region cut in two side blobs by a 3-pixel gap at
    60 % of its width; also the gap's pixels."""
    top = np.zeros((H, W), np.int32)
    top[100:130, 140:180] = 1
    predicted = predict_side_regions(lift_top_blobs(top, rig), rig) == 1
    xs = np.nonzero(predicted)[1]
    cut = int(np.percentile(xs, 60))
    columns = np.arange(W)[None, :]
    gap = predicted & (columns >= cut) & (columns < cut + 3)
    side = np.where(predicted, np.where(columns < cut, 1, 2), 0)
    side[gap] = 0
    return top, side, gap


def _segmentation(labels: np.ndarray, table_seen: np.ndarray | None = None,
                  thin: tuple[bool, ...] = ()) -> Segmentation:
    boxes, areas = boxes_from_labels(labels)
    n = len(areas)
    return Segmentation(labels=labels.astype(np.uint16), boxes=boxes, areas=areas,
                        foreground=labels > 0, depth_groups=np.zeros(n, np.int32),
                        thin=np.array(thin or (False,) * n, bool), table_seen=table_seen)


def test_side_blobs_with_the_table_seen_between_them_are_two_parts() -> None:
    rig = default_rig(W, H)
    top, side, gap = _one_top_blob_two_side_blobs(rig)
    table = side == 0   # the table seen everywhere but on the two blobs, the gap too

    def fused(table_seen, thin=(), **params):
        return fuse_views(_segmentation(top), _segmentation(side, table_seen, thin), rig=rig,
                          params=FusionParams(**params))

    result = fused(table)
    assert len(result.instances) == 2
    kept, new = result.instances
    assert kept.views == ('top', 'side') and new.views == ('side',)
    # the blob holding most of the prediction keeps the top blob's id
    assert np.array_equal(result.labels['side'] == kept.instance_id, side == 1)
    assert np.array_equal(result.labels['side'] == new.instance_id, side == 2)
    # without depth in the gap (a dark part's middle, a hole), or with one line of pixels
    # above the table across it (the part itself, lost by the cues), it may be one part
    assert len(fused(table & ~gap).instances) == 1
    bridged = table.copy()
    rows = np.nonzero(gap.any(axis=1))[0]
    bridged[rows[len(rows) // 2], :] &= ~gap[rows[len(rows) // 2], :]
    assert len(fused(bridged).instances) == 1
    # two thin blobs: a thin part's top lies within the depth's noise of the table, so its
    # middle may read as table; a thin blob beside a part that is not is still two parts
    assert len(fused(table, thin=(True, True)).instances) == 1
    assert len(fused(table, thin=(True, False)).instances) == 2
    # no depth at all, or the rule off: the top view decides, as before
    assert len(fused(None).instances) == 1
    assert len(fused(table, table_divides=False).instances) == 1


def _side_view_of_two_boxes(gap_m: float):
    """The side camera's view of two 30x20x15 mm boxes ``gap_m`` apart along x on the table:
    rgb, depth_m, per-pixel box index (-1 table), camera."""
    cam = default_rig(W, H)['side']
    renderer = MeshRenderer()
    for x0 in (-0.030 - gap_m / 2, gap_m / 2):
        v = np.array([[x, y, z] for x in (x0, x0 + 0.03) for y in (-0.01, 0.01)
                      for z in (0.0, 0.015)])
        renderer.add_mesh(v, _BOX_FACES, np.eye(4))
    res = renderer.render(cam.intrinsics, cam.T_world_camera)
    rays = np.linalg.inv(cam.intrinsics.K) @ np.vstack([
        np.mgrid[0:H, 0:W][::-1].reshape(2, -1), np.ones((1, H * W))])
    R, t = cam.T_world_camera[:3, :3], cam.T_world_camera[:3, 3]
    table_z = (-t[2] / (R[2] @ rays)).reshape(H, W)
    on_box = res.instance >= 0
    rng = np.random.default_rng(3)
    depth = np.where(on_box, res.depth_m, table_z).astype(np.float32)
    depth += rng.normal(0, 0.0005, depth.shape).astype(np.float32)
    rgb = np.where(on_box[..., None], 60.0, 150.0) + rng.normal(0, 2.0, (H, W, 3))
    return np.clip(rgb, 0, 255).astype(np.uint8), depth, res.instance, cam


_BOX_FACES = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                       [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])


def test_the_segmentation_marks_the_table_seen_in_a_gap_of_a_few_pixels() -> None:
    # 4 mm between two boxes at 0.6 m: a few pixels, which a 3x3 median would fill
    rgb, depth, instance, cam = _side_view_of_two_boxes(0.004)
    seg = segment(rgb, depth_m=depth, intrinsics=cam.intrinsics,
                  T_world_camera=cam.T_world_camera)
    assert seg.table_seen is not None and seg.table_seen.shape == depth.shape
    # the boxes' faces stand above the table (their rims may not: the depth is read at the
    # cue scale)
    inside = cv2.erode((instance >= 0).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    assert inside.any() and not seg.table_seen[inside].any()
    left, right = np.nonzero((instance == 0).any(axis=0))[0], \
        np.nonzero((instance == 1).any(axis=0))[0]
    between = np.zeros_like(seg.table_seen)
    between[:, left.max() + 1:right.min()] = True
    rows = np.nonzero((instance >= 0).any(axis=1))[0]
    band = between & (np.arange(H)[:, None] >= rows.min()) & \
        (np.arange(H)[:, None] <= rows.max()) & (instance < 0)
    assert band.any() and seg.table_seen[band].mean() > 0.5
    assert segment(rgb).table_seen is None   # colour alone: nothing to tell
