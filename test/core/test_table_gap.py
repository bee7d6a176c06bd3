"""Two side blobs that one top blob predicts: apart where the table shows between them
(:mod:`tlessbot_ros.core.localise.table_gap`), one part where something else may join them."""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.common import default_rig
from tlessbot_ros.core.localise import (
    FusionParams,
    Segmentation,
    boxes_from_labels,
    fuse_views,
    lift_top_blobs,
    predict_side_regions,
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
