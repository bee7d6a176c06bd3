"""Blobs cut by the depth's table veto out of a colour region larger than any part: table.

A colour cue marks every pixel whose colour is far from the table's dominant colour, so on a
coloured checker table it marks whole squares; the depth cue's table veto then removes the
squares where the depth reads table height. On smoothed stereo depth, noise patches 10-20 px
across rise a few millimetres, above that veto, so pieces of a square survive there as
part-sized blobs (docs/bench/table-false-parts.md). Such a piece has the colour of the
depth-vetoed table just around it, since its outline is drawn by the depth noise, not by a
colour change. So is a piece of a thin part whose own top the depth reads as table; what tells
them apart is the region of that colour: a square's runs on beyond the longest a part can look
in the view (and on to the next square of the pattern), a part's ends at the part's outline.
So a blob the depth cue does not find, with depth-vetoed table around it, is dropped when the
colour inside its outline matches that table's to within the colour cues' own smallest
cut-offs (``grey_floor``, ``lab_floor``) and the region of that colour around it is longer
than any part (``whole_parts``; without the parts' sizes nothing is dropped).
"""
from __future__ import annotations

import cv2
import numpy as np

from tlessbot_ros.core.localise.colour import rgb_to_lab
from tlessbot_ros.core.localise.params import SegmentationParams

# A blob is the depth cue's when at least this share of it is a depth candidate: it stands
# out of the table by height, whatever its colour.
DEPTH_FOUND_SHARE = 0.5
# A blob is compared with the table around it only where the depth reads table height on at
# least this share of its outside band (otherwise what surrounds it is not known to be table).
TABLE_SHARE = 0.5


def rings(blob: np.ndarray, others: np.ndarray, ring_px: int
          ) -> tuple[np.ndarray, np.ndarray]:
    """(inside, outside) bands of ``ring_px`` along the outline of ``blob`` (bool crops);
    the outside band leaves out other blobs."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring_px + 1, 2 * ring_px + 1))
    inside = blob & ~cv2.erode(blob.view(np.uint8), kernel).astype(bool)
    outside = cv2.dilate(blob.view(np.uint8), kernel).astype(bool) & ~blob & ~others
    return inside, outside


def colour_step(lab: np.ndarray, blob: np.ndarray, others: np.ndarray, table: np.ndarray,
                ring_px: int, floors: np.ndarray) -> tuple[float, np.ndarray]:
    """The largest LAB channel step from the table just outside ``blob`` to the band inside
    its outline (medians), in units of that channel's ``floors`` (L, a, b), and the inside
    band's median colour; inf when the band outside is mostly not ``table`` (depth at table
    height) or a band is too small to read. All arguments are crops of one window."""
    inside, outside = rings(blob, others, ring_px)
    seen = outside & table
    colour = np.median(lab[inside], axis=0) if inside.sum() >= 5 else np.zeros(3)
    if inside.sum() < 5 or seen.sum() < 5 or seen.sum() < TABLE_SHARE * outside.sum():
        return float('inf'), colour
    step = colour - np.median(lab[seen], axis=0)
    return float(np.max(np.abs(step) / floors)), colour


def colour_region_length(lab: np.ndarray, blob: np.ndarray, colour: np.ndarray,
                         tolerance: np.ndarray) -> int:
    """The long side (px) of the box of the region of ``colour`` (each LAB channel within
    ``tolerance``, 8-connected) that holds ``blob``, within the window ``lab`` covers."""
    same = np.all(np.abs(lab - colour) <= tolerance, axis=2) | blob
    _, regions = cv2.connectedComponents(same.view(np.uint8), connectivity=8)
    ys, xs = np.nonzero(np.isin(regions, np.unique(regions[blob])))
    return int(max(np.ptp(ys), np.ptp(xs))) + 1


def drop_blobs_without_colour_edge(foreground: np.ndarray, rgb: np.ndarray,
                                   depth_candidate: np.ndarray, depth_table: np.ndarray,
                                   params: SegmentationParams) -> np.ndarray:
    """``foreground`` (H, W) bool without its blobs that the depth cue does not find
    (``depth_candidate``, (H, W) bool), whose colour steps by less than
    ``params.colour_edge_floors`` cut-off floors from the table around them (``depth_table``,
    (H, W) bool: depth at table height) and whose colour runs on further than any part is long
    (module doc; 0 or unknown parts: unchanged)."""
    longest = max((extent[2] for extent in params.whole_parts or ()), default=0.0)
    if params.colour_edge_floors <= 0 or longest <= 0:
        return foreground
    count, blobs, stats, _ = cv2.connectedComponentsWithStats(foreground.view(np.uint8),
                                                              connectivity=8)
    found = np.bincount(blobs[depth_candidate], minlength=count)
    floors = np.array([params.grey_floor, params.lab_floor, params.lab_floor], np.float32)
    lab = None
    h, w = foreground.shape
    drop = []
    for i in np.flatnonzero(found[1:] < DEPTH_FOUND_SHARE * stats[1:, cv2.CC_STAT_AREA]) + 1:
        x, y, bw, bh = stats[i, :4]
        pad = int(np.ceil(longest)) + params.colour_edge_ring_px
        rows = slice(max(y - pad, 0), min(y + bh + pad, h))
        cols = slice(max(x - pad, 0), min(x + bw + pad, w))
        lab = rgb_to_lab(rgb) if lab is None else lab
        crop = blobs[rows, cols]
        blob = crop == i
        step, colour = colour_step(lab[rows, cols], blob, (crop > 0) & ~blob,
                                   depth_table[rows, cols], params.colour_edge_ring_px, floors)
        if step < params.colour_edge_floors and colour_region_length(
                lab[rows, cols], blob, colour, params.colour_edge_floors * floors) > longest:
            drop.append(i)
    return foreground & ~np.isin(blobs, drop) if drop else foreground
