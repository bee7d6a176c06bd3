"""A fused side region divided along a gap of the table's colour where the top view sees two
parts there (:mod:`tlessbot_ros.core.localise.gap_colour`), and nowhere else."""
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
TABLE, PART = 150, 60


def _scene(top_gap_px: int = 1, gap_colour: int = TABLE):
    """Two top blobs ``top_gap_px`` apart and their side view: one side instance over both
    predicted regions and the gap between them (a depth that fills the gap), the parts dark,
    the gap ``gap_colour``, the table light. Returns top labels, side labels, side rgb and
    the predicted side regions."""
    top = np.zeros((H, W), np.int32)
    top[100:130, 120:150] = 1
    top[100:130, 150 + top_gap_px:180 + top_gap_px] = 2
    rig = default_rig(W, H)
    pred = predict_side_regions(lift_top_blobs(top, rig), rig)
    parts = pred > 0
    rows = np.flatnonzero((pred == 1).any(axis=1) & (pred == 2).any(axis=1))
    gap = np.zeros_like(parts)
    for r in rows:
        left, right = np.flatnonzero(pred[r] == 1).max(), np.flatnonzero(pred[r] == 2).min()
        gap[r, left + 1:right] = True
    side = (parts | gap).astype(np.int32)
    rgb = np.full((H, W, 3), TABLE, np.uint8)
    rgb[parts] = PART
    rgb[gap] = gap_colour
    return top, side, rgb, pred


def _segmentation(labels: np.ndarray, thin: bool = False) -> Segmentation:
    boxes, areas = boxes_from_labels(labels.astype(np.uint16))
    n = len(areas)
    return Segmentation(labels=labels.astype(np.uint16), boxes=boxes, areas=areas,
                        foreground=labels > 0, depth_groups=np.zeros(n, np.int32),
                        thin=np.full(n, thin, bool))


def _fused(top, side, rgb, *, thin: bool = True, **params):
    return fuse_views(_segmentation(top), _segmentation(side, thin), rig=default_rig(W, H),
                      side_rgb=rgb, params=FusionParams(**params))


def test_a_table_coloured_gap_divides_a_region_where_the_top_sees_two_parts() -> None:
    top, side, rgb, pred = _scene()
    # one thin side instance over both: the fusion takes the top blobs as fragments of it
    assert len(_fused(top, side, rgb, gap_table_floors=0.0).instances) == 1
    result = _fused(top, side, rgb)
    assert len(result.instances) == 2
    labels = result.labels['side']
    for k in (1, 2):   # each part whole in one region, the two apart, in both views
        ids = np.unique(labels[pred == k])
        assert ids.size == 1 and ids[0] > 0
    assert labels[pred == 1][0] != labels[pred == 2][0]
    assert np.array_equal(labels > 0, side > 0)   # the outline does not change
    top_ids = [np.unique(result.labels['top'][top == k]) for k in (1, 2)]
    assert all(ids.size == 1 for ids in top_ids) and top_ids[0][0] != top_ids[1][0]
    assert {i.instance_id for i in result.instances if i.in_top and i.in_side} == \
        {int(labels[pred == 1][0]), int(labels[pred == 2][0])}


def test_no_division_without_a_table_coloured_gap_or_the_top_views_two_parts() -> None:
    # the gap in the parts' own colour (a dark part across a dark tile): one region
    top, side, rgb, _ = _scene(gap_colour=PART)
    assert len(_fused(top, side, rgb).instances) == 1
    # the top view sees one part there: the gap's colour alone divides nothing
    top, side, rgb, _ = _scene()
    assert len(_fused(np.where(top > 0, 1, 0), side, rgb).instances) == 1
    # a part of the table's colour is never a piece
    rgb_light = np.where((side > 0)[..., None], TABLE, rgb).astype(np.uint8)
    assert len(_fused(top, side, rgb_light).instances) == 1


def _two_side_instances(side: np.ndarray, pred: np.ndarray) -> np.ndarray:
    """The side blob as the side segmentation's touching-object separation gives it: two
    instances, the gap's pixels to the nearer part."""
    columns = np.arange(W)[None, :]
    cut = (np.flatnonzero((pred == 1).any(axis=0)).max() +
           np.flatnonzero((pred == 2).any(axis=0)).min()) // 2
    return np.where(side > 0, np.where(columns <= cut, 1, 2), 0)


def test_two_side_instances_with_a_table_coloured_seam_stay_apart() -> None:
    # the top view, farther away, sees one blob; the side segmentation has two instances
    top, side, rgb, pred = _scene()
    one_top = np.where(top > 0, 1, 0)
    two = _two_side_instances(side, pred)
    assert len(_fused(one_top, two, rgb, thin=False, gap_table_floors=0.0).instances) == 1
    result = _fused(one_top, two, rgb, thin=False)
    assert len(result.instances) == 2
    labels = result.labels['side']
    assert all(np.unique(labels[pred == k]).size == 1 for k in (1, 2))   # each part whole
    assert labels[pred == 1][0] != labels[pred == 2][0]
    # a gap that a shadow bridges across a few rows: no band divides it, but the seam
    # between the two instances is still mostly the table's colour
    gap = (side > 0) & (pred == 0)
    rows = np.flatnonzero(gap.any(axis=1))
    bridged = rgb.copy()
    bridged[rows[len(rows) // 2 - 2:len(rows) // 2 + 2]] = np.where(
        gap[rows[len(rows) // 2 - 2:len(rows) // 2 + 2], :, None], PART,
        bridged[rows[len(rows) // 2 - 2:len(rows) // 2 + 2]])
    assert len(_fused(one_top, two, bridged, thin=False).instances) == 2
    assert len(_fused(one_top, np.where(two > 0, 1, 0), bridged, thin=False).instances) == 1
    # two instances that do not touch (two blobs, or one part the cues broke up around
    # lost pixels): the fusion's own business (apart_by_table), not a seam
    apart = two.copy()
    apart[(side > 0) & (pred == 0)] = 0
    assert len(_fused(one_top, apart, rgb, thin=False).instances) == 1
    # without the table's colour between them (one part in two instances), or with the
    # side instances' evidence off: one part
    dark = _scene(gap_colour=PART)[2]
    assert len(_fused(one_top, two, dark, thin=False).instances) == 1
    assert len(_fused(one_top, two, rgb, thin=False, gap_side_instances=False).instances) == 1


def test_regions_the_fusion_already_has_apart_do_not_move() -> None:
    # a side instance that is not thin: the top view's two predictions divide it already
    top, side, rgb, _ = _scene()
    off = _fused(top, side, rgb, thin=False, gap_table_floors=0.0)
    on = _fused(top, side, rgb, thin=False)
    assert len(off.instances) == 2
    for view in ('top', 'side'):
        assert np.array_equal(off.labels[view], on.labels[view])
