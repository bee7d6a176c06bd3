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

A pattern's squares can be shorter than the parts (our simulator's checker), so a second test
reads the outline itself: a part's outline is its edge, where the colour steps all along; a
noise patch's piece of a square steps only where it meets the square's own edge. A piece of a
thin part cut out by the veto steps nowhere either, so the test also asks that the blob's
colour be common around it (a pattern's, not one part's): a blob the depth cue does not find
is dropped when under ``colour_edge_outline_share`` of its outline steps by the same
tolerance and its colour covers more than ``COMMON_COLOUR_SHARE`` of the window one part
length around it (docs/bench/smoothed-localiser.md).

A piece whose outline runs along the squares' own edges for most of its length steps there, and
one that holds both squares' colours has a median colour common nowhere; but either has only
the table's colours on both sides of its outline, where a part shows its own. So a blob the
depth cue finds on no pixel is also dropped when at least ``colour_edge_pattern_share`` of its
pixels have colours common on the table around it (each more than ``COMMON_COLOUR_SHARE`` of
the window's pixels off every blob): a noise patch between the table and candidate levels
reaches the latter nowhere, a part lying on a square of its colour does in places
(docs/bench/checker-false-parts.md).
"""
from __future__ import annotations

import cv2
import numpy as np

from tlessbot_ros.core.localise.blob_split import padded_window
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
# An outline pixel shows a colour step when the colour spans a tolerance within this many
# pixels of it: the outline the cues draw lies within a pixel or two of a part's edge.
OUTLINE_REACH_PX = 2
# A blob's colour is the pattern's when more than this share of the window one part length
# around it has it: a pattern's squares cover a large share of any window (a checker half of
# it), a part's colour at most the part's own area (under a tenth of that window).
COMMON_COLOUR_SHARE = 0.2
# The table's common colours are looked for among its most common colour bins, this many (a
# pattern has a few colours; each common one fills a good share of the bins' pixels).
COMMON_BINS_TRIED = 8


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


def outline_step_share(lab: np.ndarray, blob: np.ndarray, tolerance: np.ndarray,
                       reach_px: int) -> float:
    """The share of ``blob``'s outline pixels where the colour steps: some LAB channel (3 x 3
    means, against sensor noise) spans more than ``tolerance`` within ``reach_px`` of the
    pixel. All arguments are crops of one window; 1.0 for a blob too small to have an inside."""
    mask = blob.view(np.uint8)
    outline = blob & ~cv2.erode(mask, np.ones((3, 3), np.uint8)).astype(bool)
    if not outline.any():
        return 1.0
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach_px + 1, 2 * reach_px + 1))
    mean = cv2.blur(np.ascontiguousarray(lab, np.float32), (3, 3))
    span = cv2.dilate(mean, kernel) - cv2.erode(mean, kernel)
    steps = np.any(span[outline] > tolerance.astype(np.float32), axis=1)
    return float(np.count_nonzero(steps)) / len(steps)


def colour_share_around(lab: np.ndarray, blob: np.ndarray, tolerance: np.ndarray) -> float:
    """The share of the pixels around ``blob`` (the window ``lab`` covers, less the blob) whose
    colour is the blob's median colour, each LAB channel within ``tolerance``."""
    colour = np.median(lab[blob], axis=0).astype(np.float64)
    same = cv2.inRange(lab, colour - tolerance, colour + tolerance).astype(bool) & ~blob
    return float(np.count_nonzero(same)) / max(blob.size - int(np.count_nonzero(blob)), 1)



def drop_blobs_without_colour_edge(foreground: np.ndarray, rgb: np.ndarray,
                                   depth_candidate: np.ndarray, depth_table: np.ndarray,
                                   params: SegmentationParams) -> np.ndarray:
    """``foreground`` (H, W) bool without its blobs that the depth cue does not find
    (``depth_candidate``, (H, W) bool), mostly of the colour of the table around them (within
    ``params.colour_edge_floors`` cut-off floors; ``depth_table``, (H, W) bool: depth at table
    height), where that colour runs on further than any part is long, or without a colour
    step along most of their outline in a colour common around them (module doc; 0 or
    unknown parts: unchanged)."""
    longest = max((extent[2] for extent in params.whole_parts or ()), default=0.0)
    if params.colour_edge_floors <= 0 or longest <= 0:
        return foreground
    count, blobs, stats, _ = cv2.connectedComponentsWithStats(foreground.view(np.uint8),
                                                              connectivity=8)
    found = np.bincount(blobs[depth_candidate], minlength=count)
    tolerance = params.colour_edge_floors * np.array(
        [params.grey_floor, params.lab_floor, params.lab_floor], np.float64)
    area = stats[1:, cv2.CC_STAT_AREA]
    # blobs under half the smallest instance are dropped anyway (instances_at_scale keeps
    # min_area_px at its scale, which rounds a little below it)
    tested = np.flatnonzero((found[1:] < DEPTH_FOUND_SHARE * area) &
                            (area >= params.min_area_px // 2)) + 1
    if not len(tested):   # most frames: no full-resolution LAB image to make
        return foreground
    lab = rgb_to_lab(rgb)
    drop = [i for i in tested if _table_piece(lab, blobs, stats[i, :4], int(i), depth_table,
                                              longest, tolerance, params, found[i] == 0)]
    return foreground & ~np.isin(blobs, drop) if drop else foreground


def _table_piece(lab: np.ndarray, blobs: np.ndarray, box: np.ndarray, i: int,
                 depth_table: np.ndarray, longest: float, tolerance: np.ndarray,
                 params: SegmentationParams, depth_free: bool) -> bool:
    """Whether blob ``i`` of ``blobs`` (its ``box``) is a piece of the table's pattern: of
    the colour of the table around it in a region longer than any part, or without a colour
    step along most of its outline in a colour common around it, or, where no pixel of it is
    a depth candidate (``depth_free``), mostly in colours common on the table (module doc)."""
    near = padded_window(box, params.colour_edge_ring_px + 1, blobs.shape)
    crop = blobs[near]
    blob = crop == i
    around = padded_window(box, int(np.ceil(longest)) + 1, blobs.shape)
    share, colour = table_colour_share(lab[near], blob, (crop > 0) & ~blob, depth_table[near],
                                       params.colour_edge_ring_px, tolerance)
    if share >= TABLE_COLOUR_SHARE and \
            colour_region_length(lab[around], blobs[around] == i, colour, tolerance) > longest:
        return True
    if outline_step_share(lab[near], blob, tolerance, OUTLINE_REACH_PX) < \
            params.colour_edge_outline_share and \
            colour_share_around(lab[around], blobs[around] == i, tolerance) > COMMON_COLOUR_SHARE:
        return True
    share = params.colour_edge_pattern_share
    if not depth_free or share <= 0:
        return False
    if pattern_colour_share(lab[around], blobs[around] == i, blobs[around] == 0, tolerance,
                            share) >= share:
        return True
    return params.colour_edge_blend_px > 0 and blend_pattern_share(
        lab[around], blobs[around] == i, blobs[around] == 0, tolerance,
        params.colour_edge_blend_px) >= share


def colour_bins(colours: np.ndarray, tolerance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The bins one ``tolerance`` wide that (N, 3) LAB ``colours`` fall in: ((K, 3) bin
    centres, (K,) pixel counts), each bin once."""
    bins = np.floor(colours / tolerance).astype(np.int64) + 1024   # colours as bin numbers
    keys, counts = np.unique((bins[:, 0] * 4096 + bins[:, 1]) * 4096 + bins[:, 2],
                             return_counts=True)
    index = np.stack([keys // 4096 ** 2, keys // 4096 % 4096, keys % 4096], axis=1)
    return (index - 1024 + 0.5) * tolerance, counts


def pattern_colour_share(lab: np.ndarray, blob: np.ndarray, table: np.ndarray,
                         tolerance: np.ndarray, decide_at: float | None = None) -> float:
    """The share of ``blob``'s pixels whose colour is one of the table's own: each LAB channel
    within ``tolerance`` of the colour of more than ``COMMON_COLOUR_SHARE`` of the ``table``
    pixels (the window's pixels off every blob, every second row and column). A pattern's
    piece holds its squares' colours, one or both; a part's colour covers at most its own area.
    With ``decide_at``, counting stops once the share is known to be on one side of it (the
    value returned is then on that side). Crops of one window; 0 without table to read."""
    reference = np.ascontiguousarray(lab[::2, ::2][table[::2, ::2]])[:, None, :]
    if len(reference) < 5:
        return 0.0
    inside = lab[blob]
    centres, counts = colour_bins(inside, tolerance)
    need = COMMON_COLOUR_SHARE * len(reference)
    left = len(inside)
    common = 0
    for k in np.argsort(-counts):   # the blob's main colours first
        centre = centres[k]
        same = cv2.inRange(reference, centre - tolerance, centre + tolerance)
        common += int(counts[k]) if np.count_nonzero(same) > need else 0
        left -= int(counts[k])
        if decide_at is not None and (common >= decide_at * len(inside) or
                                      common + left < decide_at * len(inside)):
            break
    return common / len(inside)


def common_colours(lab: np.ndarray, table: np.ndarray, tolerance: np.ndarray) -> np.ndarray:
    """(K, 3) LAB colours that more than ``COMMON_COLOUR_SHARE`` of the ``table`` pixels (every
    second row and column) lie within ``tolerance`` of: the pattern's colours, at most one per
    tolerance box, tried in order of the most common bins one tolerance wide."""
    reference = lab[::2, ::2][table[::2, ::2]].astype(np.float64)
    if len(reference) < 5:
        return np.zeros((0, 3))
    centres, counts = colour_bins(reference, tolerance)
    kept: list[np.ndarray] = []
    for k in np.argsort(-counts)[:COMMON_BINS_TRIED]:
        centre = centres[k]
        if any(np.all(np.abs(centre - c) <= tolerance) for c in kept):
            continue
        within = np.all(np.abs(reference - centre) <= tolerance, axis=1)
        if np.count_nonzero(within) > COMMON_COLOUR_SHARE * len(reference):
            kept.append(centre)
    return np.array(kept).reshape(-1, 3)


def blend_pattern_share(lab: np.ndarray, blob: np.ndarray, table: np.ndarray,
                        tolerance: np.ndarray, reach_px: int) -> float:
    """The share of ``blob``'s pixels in one of the table's common colours
    (:func:`common_colours`) or between two of them (within ``tolerance`` of the line from one
    to the other) where pixels of both lie within ``reach_px``: a square's edge, blurred by the
    lens and the sensor, has colours neither square has. A part whose colour lies between two
    of the table's has it inside its outline too, away from the squares' colours. Crops of one
    window; 0 without table to read."""
    colours = common_colours(lab, table, tolerance)
    if not len(colours) or not blob.any():
        return 0.0
    scaled, centres = lab[blob] / tolerance, colours / tolerance
    pattern = np.zeros(len(scaled), bool)
    for centre in centres:
        pattern |= np.all(np.abs(scaled - centre) <= 1.0, axis=1)
    if len(centres) < 2 or pattern.all():
        return float(pattern.mean())
    rows, cols = np.nonzero(blob)   # only the blob's box and its reach are looked at
    box = (slice(max(int(rows.min()) - reach_px, 0), int(rows.max()) + reach_px + 1),
           slice(max(int(cols.min()) - reach_px, 0), int(cols.max()) + reach_px + 1))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * reach_px + 1, 2 * reach_px + 1))
    near = [cv2.dilate(cv2.inRange(lab[box], c - tolerance, c + tolerance), kernel)[blob[box]]
            > 0 for c in colours]
    for a in range(len(centres)):
        for b in range(a + 1, len(centres)):
            between = np.flatnonzero(near[a] & near[b] & ~pattern)
            if not len(between):
                continue
            step = centres[b] - centres[a]
            t = np.clip((scaled[between] - centres[a]) @ step / (step @ step), 0.0, 1.0)
            on_line = np.all(np.abs(scaled[between] - centres[a] - t[:, None] * step) <= 1.0,
                             axis=1)
            pattern[between[on_line]] = True
    return float(pattern.mean())
