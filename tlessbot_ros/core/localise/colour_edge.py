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
So a blob the depth cue does not find, with depth-vetoed table around it, is dropped when most
of the band inside its outline has that table's colour, to within the colour cues' own
smallest cut-offs (``grey_floor``, ``lab_floor``), and the region of that colour around it is
longer than any part (``whole_parts``; without the parts' sizes nothing is dropped).
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
# A blob has the table's colour when most of the band inside its outline has it (a median
# colour would not do: two parts' colours in one blob can average to the table's).
TABLE_COLOUR_SHARE = 0.5


def rings(blob: np.ndarray, others: np.ndarray, ring_px: int
          ) -> tuple[np.ndarray, np.ndarray]:
    """(inside, outside) bands of ``ring_px`` along the outline of ``blob`` (bool crops);
    the outside band leaves out other blobs."""
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ring_px + 1, 2 * ring_px + 1))
    inside = blob & ~cv2.erode(blob.view(np.uint8), kernel).astype(bool)
    outside = cv2.dilate(blob.view(np.uint8), kernel).astype(bool) & ~blob & ~others
    return inside, outside


def table_colour_share(lab: np.ndarray, blob: np.ndarray, others: np.ndarray,
                       table: np.ndarray, ring_px: int, tolerance: np.ndarray
                       ) -> tuple[float, np.ndarray]:
    """The share of the band inside ``blob``'s outline whose colour is the table's just
    outside it (each LAB channel within ``tolerance`` of the median of the outside band's
    ``table`` pixels: depth at table height), and that colour; 0 when the outside band is
    mostly not table or a band is too small to read. All arguments are crops of one window."""
    inside, outside = rings(blob, others, ring_px)
    seen = outside & table
    if inside.sum() < 5 or seen.sum() < 5 or seen.sum() < TABLE_SHARE * outside.sum():
        return 0.0, np.zeros(3)
    colour = np.median(lab[seen], axis=0).astype(np.float64)
    same = cv2.inRange(lab[inside][:, None, :], colour - tolerance, colour + tolerance)
    return float(np.count_nonzero(same)) / len(same), colour


def colour_region_length(lab: np.ndarray, blob: np.ndarray, colour: np.ndarray,
                         tolerance: np.ndarray) -> int:
    """The long side (px) of the box of the region of ``colour`` (each LAB channel within
    ``tolerance``, 8-connected) that holds ``blob``, within the window ``lab`` covers."""
    colour = np.asarray(colour, np.float64)
    same = cv2.inRange(lab, colour - tolerance, colour + tolerance).astype(bool) | blob
    _, regions, stats, _ = cv2.connectedComponentsWithStats(same.view(np.uint8),
                                                            connectivity=8)
    region = regions.flat[np.argmax(blob)]   # blob is one 8-connected piece of ``same``
    return int(stats[region, cv2.CC_STAT_WIDTH:cv2.CC_STAT_HEIGHT + 1].max())


def _window(box: np.ndarray, pad: int, shape: tuple[int, ...]) -> tuple[slice, slice]:
    """The rows and columns of an (x, y, w, h) box grown by ``pad``, within ``shape``."""
    x, y, w, h = (int(v) for v in box)
    return (slice(max(y - pad, 0), min(y + h + pad, shape[0])),
            slice(max(x - pad, 0), min(x + w + pad, shape[1])))


def drop_blobs_without_colour_edge(foreground: np.ndarray, rgb: np.ndarray,
                                   depth_candidate: np.ndarray, depth_table: np.ndarray,
                                   params: SegmentationParams) -> np.ndarray:
    """``foreground`` (H, W) bool without its blobs that the depth cue does not find
    (``depth_candidate``, (H, W) bool), mostly of the colour of the table around them (within
    ``params.colour_edge_floors`` cut-off floors; ``depth_table``, (H, W) bool: depth at table
    height), where that colour runs on further than any part is long (module doc; 0 or
    unknown parts: unchanged)."""
    longest = max((extent[2] for extent in params.whole_parts or ()), default=0.0)
    if params.colour_edge_floors <= 0 or longest <= 0:
        return foreground
    count, blobs, stats, _ = cv2.connectedComponentsWithStats(foreground.view(np.uint8),
                                                              connectivity=8)
    found = np.bincount(blobs[depth_candidate], minlength=count)
    tolerance = params.colour_edge_floors * np.array(
        [params.grey_floor, params.lab_floor, params.lab_floor], np.float64)
    drop = []
    area = stats[1:, cv2.CC_STAT_AREA]
    # blobs under half the smallest instance are dropped anyway (instances_at_scale keeps
    # min_area_px at its scale, which rounds a little below it)
    tested = np.flatnonzero((found[1:] < DEPTH_FOUND_SHARE * area) &
                            (area >= params.min_area_px // 2)) + 1
    if not len(tested):   # most frames: no full-resolution LAB image to make
        return foreground
    lab = rgb_to_lab(rgb)
    for i in tested:
        near = _window(stats[i, :4], params.colour_edge_ring_px + 1, foreground.shape)
        crop = blobs[near]
        blob = crop == i
        share, colour = table_colour_share(lab[near], blob, (crop > 0) & ~blob,
                                           depth_table[near], params.colour_edge_ring_px,
                                           tolerance)
        if share < TABLE_COLOUR_SHARE:
            continue
        around = _window(stats[i, :4], int(np.ceil(longest)) + 1, foreground.shape)
        if colour_region_length(lab[around], blobs[around] == i, colour, tolerance) > longest:
            drop.append(i)
    return foreground & ~np.isin(blobs, drop) if drop else foreground
