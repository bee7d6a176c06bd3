"""The colour likeness of a window's pixels (core/pose/silhouette.py: part_likeness): a pixel
is like the part or like its surroundings by its colour alone, so each distinct colour is
measured once and every pixel of that colour gets its answer."""
from __future__ import annotations

import numpy as np


def _window(seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A grey part on a brown table, 8-bit noise: (rgb, part pixels, surroundings)."""
    rng = np.random.default_rng(seed)
    rgb = np.empty((60, 80, 3), np.float64)
    rgb[:] = (120, 90, 60)
    part = np.zeros((60, 80), bool)
    part[15:45, 20:60] = True
    rgb[part] = (160, 160, 165)
    rgb = np.clip(rgb + rng.normal(0, 3, rgb.shape), 0, 255).astype(np.uint8)
    inside = np.zeros_like(part)
    inside[20:40, 25:55] = True
    ring = np.zeros_like(part)
    ring[:5] = ring[-5:] = True
    return rgb, inside, ring


def test_each_distinct_colour_is_measured_once_and_every_pixel_gets_its_answer(monkeypatch):
    from tlessbot_ros.core.pose import silhouette

    rgb, inside, ring = _window()
    where = np.ones(inside.shape, bool)
    sizes: list[int] = []
    original = silhouette._nearest

    def counted(query, samples):
        sizes.append(len(query))
        return original(query, samples)

    monkeypatch.setattr(silhouette, '_nearest', counted)
    like = silhouette.part_likeness(rgb, inside, ring, where)
    distinct = len(np.unique(rgb.reshape(-1, 3), axis=0))
    assert sizes == [distinct, distinct] and distinct < where.sum()
    # pixel by pixel, as measured one at a time
    query = rgb[where].astype(np.float32)
    rng = np.random.default_rng(0)
    colour = rgb.astype(np.float32)
    d_part = np.sqrt(np.maximum(original(query, silhouette._samples(colour, inside, rng)), 0))
    d_ring = np.sqrt(np.maximum(original(query, silhouette._samples(colour, ring, rng)), 0))
    clear = np.abs(d_ring - d_part) > 0.25 * (d_ring + d_part)
    assert np.array_equal(like[where], np.where(clear, np.sign(d_ring - d_part), 0))
    part = np.zeros(inside.shape, bool)
    part[15:45, 20:60] = True
    assert (like[part] > 0).mean() > 0.9 and (like[~part] < 0).mean() > 0.9
