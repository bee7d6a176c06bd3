"""Blobs with no colour edge at their outline: table, not parts.

A colour cue marks every pixel whose colour is far from the table's dominant colour, so on a
coloured checker table it marks whole squares; the depth cue's table veto then removes the
squares where the depth reads table height. On smoothed stereo depth, noise patches 10-20 px
across rise a few millimetres, above that veto, so pieces of a square survive there as
part-sized blobs (docs/bench/table-false-parts.md). Such a piece has the colour of the table
just outside it, since its outline is drawn by the depth noise, not by a colour change; a part
found by colour differs in colour from the table around it. So a blob that the depth cue does
not find is dropped when the colour inside its outline matches the colour just outside it, to
within the colour cues' own smallest cut-offs (``grey_floor``, ``lab_floor``).
"""
from __future__ import annotations

import cv2
import numpy as np

from tlessbot_ros.core.localise.colour import rgb_to_lab
from tlessbot_ros.core.localise.params import SegmentationParams

# A blob is the depth cue's when at least this share of it is a depth candidate: it stands
# out of the table by height, whatever its colour.
DEPTH_FOUND_SHARE = 0.5


def rings(blob: np.ndarray, others: np.ndarray, ring_px: int
           ) -> tuple[np.ndarray, np.ndarray]:
    """(inside, outside) bands of ``ring_px`` along the outline of ``blob`` (bool crops);
    the outside band leaves out other blobs."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring_px + 1, 2 * ring_px + 1))
    inside = blob & ~cv2.erode(blob.view(np.uint8), kernel).astype(bool)
    outside = cv2.dilate(blob.view(np.uint8), kernel).astype(bool) & ~blob & ~others
    return inside, outside


def colour_step(rgb: np.ndarray, blob: np.ndarray, others: np.ndarray, ring_px: int,
                floors: np.ndarray) -> float:
    """The largest LAB channel step across the outline of ``blob`` (median of the band inside
    less that of the band outside), in units of that channel's ``floors`` (L, a, b); inf
    when a band is too small to read."""
    inside, outside = rings(blob, others, ring_px)
    if inside.sum() < 5 or outside.sum() < 5:
        return float('inf')
    lab = rgb_to_lab(np.ascontiguousarray(rgb))
    step = np.median(lab[inside], axis=0) - np.median(lab[outside], axis=0)
    return float(np.max(np.abs(step) / floors))


def drop_blobs_without_colour_edge(foreground: np.ndarray, rgb: np.ndarray,
                                   depth_candidate: np.ndarray,
                                   params: SegmentationParams) -> np.ndarray:
    """``foreground`` (H, W) bool without its blobs that the depth cue does not find
    (``depth_candidate``, (H, W) bool) and whose colour steps by less than
    ``params.colour_edge_floors`` cut-off floors across their outline (0: unchanged)."""
    if params.colour_edge_floors <= 0:
        return foreground
    count, blobs, stats, _ = cv2.connectedComponentsWithStats(foreground.view(np.uint8),
                                                              connectivity=8)
    if count <= 1:
        return foreground
    found = np.bincount(blobs[depth_candidate], minlength=count)
    floors = np.array([params.grey_floor, params.lab_floor, params.lab_floor], np.float32)
    pad = params.colour_edge_ring_px + 1
    h, w = foreground.shape
    drop = []
    for i in range(1, count):
        x, y, bw, bh, area = stats[i]
        if found[i] >= DEPTH_FOUND_SHARE * area:
            continue
        rows = slice(max(y - pad, 0), min(y + bh + pad, h))
        cols = slice(max(x - pad, 0), min(x + bw + pad, w))
        crop = blobs[rows, cols]
        blob = crop == i
        if colour_step(rgb[rows, cols], blob, (crop > 0) & ~blob, params.colour_edge_ring_px,
                       floors) < params.colour_edge_floors:
            drop.append(i)
    if not drop:
        return foreground
    return foreground & ~np.isin(blobs, drop)
