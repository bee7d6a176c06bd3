"""Cluttered training crops (sim.clutter): synthetic patches, no rendering."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.sim.clutter import ClutterParams, Patch, clutter_crop, clutter_crops


def _patch(h: int, w: int, value: int, distance: float = 0.5) -> Patch:
    rgb = np.full((h, w, 3), value, np.uint8)
    mask = np.zeros((h, w), bool)
    mask[2:-2, 2:-2] = True
    return Patch(rgb, mask, distance)


def test_the_box_surrounds_the_visible_part():
    target = _patch(20, 30, 250)
    pool = [_patch(10, 10, 30), _patch(15, 8, 90, distance=1.0)]
    rng = np.random.default_rng(0)
    for _ in range(30):
        crop = clutter_crop(target, pool, rng)
        assert crop.mask.any()
        rows, cols = np.nonzero(crop.mask)
        x, y, w, h = crop.box
        # the loose box is grown by at most 30 % and shifted by at most 10 % of its side
        assert x <= cols.mean() <= x + w and y <= rows.mean() <= y + h
        assert w >= 0.9 * (np.ptp(cols) + 1) and h >= 0.9 * (np.ptp(rows) + 1)
        # neighbours over the part hide at most max_cover of it
        assert crop.mask.sum() >= (1 - ClutterParams().max_cover) * 26 * 16 - 1


def test_a_background_crop_has_no_part_and_the_same_kind_of_box():
    target = _patch(20, 30, 250)
    crop = clutter_crop(target, [_patch(10, 10, 30)], np.random.default_rng(1),
                        with_target=False)
    assert not crop.mask.any()
    assert 26 <= crop.box[2] <= 26 * 1.3 + 1


def test_crops_are_deterministic_and_labelled():
    targets = [(3, _patch(20, 30, 250)), (5, _patch(12, 12, 200))]
    pool = [p for _, p in targets]
    a = list(clutter_crops(targets, pool, copies=3, seed=7, background_share=0.5))
    b = list(clutter_crops(targets, pool, copies=3, seed=7, background_share=0.5))
    assert [i for i, _ in a] == [i for i, _ in b]
    assert all(np.array_equal(x.rgb, y.rgb) for (_, x), (_, y) in zip(a, b))
    labels = {i for i, _ in a}
    assert labels <= {3, 5, -1} and len(a) == 6
    assert all((i == -1) == (not c.mask.any()) for i, c in a)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match='context'):
        ClutterParams(context=(0.5, 2.0))
    with pytest.raises(ValueError, match='empty'):
        clutter_crop(Patch(np.zeros((4, 4, 3), np.uint8), np.zeros((4, 4), bool), 0.5), [],
                     np.random.default_rng(0))
