"""The localisation building blocks that segment() and fuse_views() use, each on its own."""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.localise import (
    SegmentationParams,
    hed_masks,
    lab_masks,
    relabel_sequential,
    remove_trend,
    rgb_to_hed,
    rgb_to_lab,
    watershed_refine,
)


def _table_with_patch() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(scene, empty table, patch mask): a grey 120x160 table with a pink 30x40 patch."""
    rng = np.random.default_rng(0)
    table = np.clip(rng.normal(150, 2, (120, 160, 3)), 0, 255).astype(np.uint8)
    scene = table.copy()
    patch = np.zeros((120, 160), bool)
    patch[40:70, 60:100] = True
    scene[patch] = (235, 120, 175)
    return scene, table, patch


def test_remove_trend_flattens_uneven_lighting() -> None:
    yy, xx = np.mgrid[0:120, 0:160].astype(np.float32)
    channel = 50 + 0.2 * xx + 0.001 * (yy - 60) ** 2
    channel[40:60, 50:80] += 40  # an object, ignored by the robust fit
    flat = remove_trend(channel)
    background = np.ones_like(flat, bool)
    background[40:60, 50:80] = False
    assert np.abs(flat[background]).max() < 1.5
    assert abs(float(np.median(flat[~background])) - 40) < 1.0


def test_hed_and_lab_masks_find_a_patch_with_and_without_the_empty_table() -> None:
    scene, table, patch = _table_with_patch()
    params = SegmentationParams()
    for masks, image, reference in (
            (hed_masks, rgb_to_hed(scene, dark_level=10), rgb_to_hed(table, dark_level=10)),
            (lab_masks, rgb_to_lab(scene), rgb_to_lab(table))):
        for ref in (None, reference):
            candidate, sure = masks(image, params, reference=ref)
            assert candidate.shape == sure.shape == patch.shape
            assert not (sure & ~candidate).any()
            assert candidate[patch].all()
            assert (candidate & ~patch).sum() < 0.001 * patch.size  # table noise


def test_watershed_refine_stops_at_the_edge() -> None:
    scene, _, patch = _table_with_patch()
    candidate = np.zeros_like(patch)
    candidate[35:75, 55:105] = True  # a loose guess around the patch
    sure = np.zeros_like(patch)
    sure[50:60, 75:85] = True
    out = watershed_refine(scene, candidate, sure, band_px=4)
    assert (out & patch).sum() / (out | patch).sum() > 0.9
    assert not watershed_refine(scene, candidate, np.zeros_like(patch)).any()


def test_relabel_sequential_renumbers_by_id() -> None:
    labels = np.array([[0, 9, 9], [4, 0, 30]], np.int32)
    out = relabel_sequential(labels)
    assert out.dtype == np.uint16
    np.testing.assert_array_equal(out, [[0, 2, 2], [1, 0, 3]])


def test_segment_times_each_cue() -> None:
    from tlessbot_ros.core.localise import segment

    scene, table, _ = _table_with_patch()
    seg = segment(scene, background=table)
    assert seg.count == 1
    assert set(seg.cues) == {'watershed', 'hed', 'lab', 'background'}
    assert {'lab', 'cue_watershed', 'cue_hed', 'cue_lab', 'cues', 'watershed', 'instances',
            'total'} == set(seg.timings_ms)
