"""A fused side region that a table-coloured gap divides where the views' own regions see
two parts there.

A stereo camera matches a window of its two images, so where the window straddles a part's
edge the table beside it takes the part's depth: a gap of a few pixels between two parts is
filled, the depth calls it a part, and the side segmentation gives the two parts one blob.
The top view, farther away, mostly sees them as one blob too, so the fusion joins them. The
colour image still shows the table in the gap where it is lit.

The gap's colour alone is not enough to divide a region: a shading line across one part, a
part lying on a tile of its own colour, look alike. So the rule acts only where another cue
has two parts there. After the fusion, in each side region of one id, the pixels within
``floors`` (per LAB channel) of the nearest pixel outside every blob are **table-coloured**.

* Those in bands narrower than a disc of ``band_px`` px (an opening; at least 3 px wide)
  that reach the region's outline are taken out (a gap between two parts opens onto the
  table; a slot or a hole through one part is closed by it). Where that leaves two or more
  **pieces** that could each be a part (``min_piece_px`` pixels, a disc of ``band_px``
  inside, under half of them table-coloured, a median colour unlike the band's) and
  different top blobs (their predicted side regions, before the fusion joined any) or
  different side instances hold them, the region is divided along the band, each pixel to
  the nearest piece.
* Else, two side instances of one blob in the region (the side segmentation's
  touching-object separation) stay apart where the seam between them (the pixels within
  ``band_px`` of both) is mostly table-coloured, reaches the outline, and neither instance
  has the seam's colour. Two instances that do not touch are left as the fusion has them:
  what lies between them may be a part's pixels the cues lost, not the table.

The piece holding most of the region's own prediction keeps its id; a piece that its own
top blob holds takes that blob back (a new id in both views, or the id of the blob's
instance when it has no side pixels); any other piece gets a new id, seen from the side.

It acts only on a region the fusion gave one id, so where the side depth or the top view's
prediction already had the parts apart nothing moves. The table is read where it lies (the
nearest table pixel, not a median of the table around the blob), so a checkered or grained
table of any colour works; a part of the table's colour is never a piece (its pixels are
table-coloured), nor is a dark part across a dark tile (its colour is the gap's).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np
from scipy import ndimage

from tlessbot_ros.core.localise.blob_split import fill_from_nearest, padded_window, pair_roots
from tlessbot_ros.core.localise.colour import rgb_to_lab
from tlessbot_ros.core.localise.cues import opened
from tlessbot_ros.core.localise.instances import boxes_from_labels

if TYPE_CHECKING:
    from tlessbot_ros.core.localise.segmentation import Segmentation


def apart_by_gap_colour(side_labels: np.ndarray, top_labels: np.ndarray, pred: np.ndarray,
                        top: Segmentation, side: Segmentation, side_rgb: np.ndarray,
                        next_id: int, *, floors: np.ndarray, band_px: int,
                        min_piece_px: float, side_instances: bool = True
                        ) -> tuple[int, set[int]]:
    """Divide the fused side regions that a table-coloured gap divides where the top view's
    own blobs, or the side segmentation's own instances (``side_instances``), hold the pieces
    apart too (see the module).

    Args:
        side_labels: (H, W) uint16 fused side labels, changed in place.
        top_labels: (H', W') uint16 fused top labels, changed in place (a piece given back to
            its top blob takes that blob's pixels here).
        pred: (H, W) predicted side regions of the top segmentation's own blobs (their ids
            as in ``top.labels``).
        top, side: the two views' segmentations (``top.labels``: the top view's own blobs;
            ``side.labels``: the side view's own instances).
        side_rgb: (H, W, 3) uint8 side image.
        next_id: the first free id.
        floors: (3,) LAB tolerance (L, a, b) of a table-coloured pixel.
        band_px: the widest band of table colour that is a gap (radius of the opening, px).
        min_piece_px: the smallest piece that can be a part (px).
        side_instances: whether two side instances stand in for two top blobs.

    Returns:
        The next free id, and the ids of the regions divided (old and new).
    """
    divided: set[int] = set()
    boxes, areas = boxes_from_labels(side_labels)
    margin = 2 * band_px + 3
    for k in (1 + np.flatnonzero(areas >= 2 * min_piece_px)).tolist():
        window = padded_window(boxes[k - 1], margin, side_labels.shape)
        region = side_labels[window] == k
        holders = [pred[window]] + ([side.labels[window]] if side_instances else [])
        if not any(_two_hold(m[region], min_piece_px / 3) for m in holders):
            continue   # neither view has two parts here: the gap's colour alone divides nothing
        off = (side_labels[window] == 0) & (side.labels[window] == 0)
        coloured = _table_coloured(region, off, side_rgb[window], floors)
        if coloured is None:
            continue
        groups = _gap_pieces(region, *coloured, holders, floors, band_px, min_piece_px)
        if groups is None and side_instances:
            groups = _seam_pieces(region, *coloured, side.labels[window], floors, band_px,
                                  min_piece_px)
        if groups is None:
            continue
        keys, grouped = groups
        kept = int(np.argmax([np.count_nonzero((grouped == g + 1) & (pred[window] == k))
                              for g in range(len(keys))]))
        blobs = [key[0] for key in keys]
        out = side_labels[window]
        for g, (blob_id, _) in enumerate(keys):
            if g == kept:
                continue
            new = 0
            own_blob = blob_id > 0 and blobs.count(blob_id) == 1 and blob_id != k
            if own_blob:   # the top view's own blob of this piece
                new = _given_back(blob_id, k, top, top_labels, side_labels)
            if new == 0:
                new, next_id = next_id, next_id + 1
                if own_blob:
                    top_labels[(top.labels == blob_id) & (top_labels == k)] = new
            out[grouped == g + 1] = new
            divided.update((k, new))
    return next_id, divided


def _two_hold(ids: np.ndarray, least_px: float) -> bool:
    """Whether two or more non-zero ids each hold ``least_px`` of ``ids``."""
    return bool(np.count_nonzero(np.bincount(ids[ids > 0]) >= least_px) >= 2)


def _given_back(blob_id: int, k: int, top: Segmentation, top_labels: np.ndarray,
                side_labels: np.ndarray) -> int:
    """The fused id of top blob ``blob_id`` when it is an instance of its own with no side
    pixels (a piece of region ``k`` joins it), else 0 (a new id)."""
    ids = top_labels[top.labels == blob_id]
    ids = ids[ids > 0]
    if not ids.size:
        return 0
    fused = int(np.bincount(ids).argmax())
    if fused == k or np.any(side_labels == fused):
        return 0
    return fused


def _table_coloured(region: np.ndarray, off: np.ndarray, rgb: np.ndarray,
                    floors: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """The window's LAB (3 x 3 blur) and the region's pixels within ``floors`` of the nearest
    pixel more than 1 px outside every blob (``off``: outside every blob); None without one."""
    reference = cv2.erode(off.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    if not reference.any():
        return None
    lab = rgb_to_lab(cv2.blur(rgb, (3, 3)))
    nearest = ndimage.distance_transform_edt(~reference, return_distances=False,
                                             return_indices=True)
    table_like = region & (np.abs(lab - lab[nearest[0], nearest[1]]) <= floors).all(axis=2)
    return lab, table_like


def _gap_pieces(region: np.ndarray, lab: np.ndarray, table_like: np.ndarray,
                holders: list[np.ndarray], floors: np.ndarray, band_px: int,
                min_piece_px: float) -> tuple[list[tuple[int, ...]], np.ndarray] | None:
    """The pieces of one region that a table-coloured band leaves, grouped by what holds
    each (its top blob in ``holders[0]``, its side instance in ``holders[1]`` when given:
    the id holding a third of it, 0 for none): the groups' keys and the region's pixels by
    group ((h, w) int32, ``g + 1`` for ``keys[g]``); None where fewer than two groups are
    left (all cut to the region's window; ``lab``, ``table_like``: :func:`_table_coloured`)."""
    band = opened(table_like, 1) & ~opened(table_like, band_px)
    if not band.any() or not _open_to_table(band, ~ndimage.binary_fill_holes(region)):
        return None
    count, parts = cv2.connectedComponents((region & ~band).view(np.uint8), connectivity=8)
    band_colour = np.median(lab[band], axis=0)
    disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_px + 1, 2 * band_px + 1))
    keys: list[tuple[int, ...]] = []
    grouped = np.zeros(region.shape, np.int32)
    for c in range(1, count):
        piece = parts == c
        size = int(np.count_nonzero(piece))
        if size < min_piece_px or 2 * np.count_nonzero(piece & table_like) >= size or \
                not cv2.erode(piece.view(np.uint8), disc).any() or \
                (np.abs(np.median(lab[piece], axis=0) - band_colour) <= floors).all():
            continue
        key = tuple(_holder(m[piece], size) for m in holders)
        if not any(key):
            continue   # no view's own region holds it: nothing tells whose it is
        if key not in keys:
            keys.append(key)
        grouped[piece] = keys.index(key) + 1
    if len(keys) < 2:
        return None
    fill_from_nearest(grouped, region & (grouped == 0))
    grouped[~region] = 0
    return keys, grouped


def _seam_pieces(region: np.ndarray, lab: np.ndarray, table_like: np.ndarray,
                 own: np.ndarray, floors: np.ndarray, band_px: int, min_piece_px: float
                 ) -> tuple[list[tuple[int, ...]], np.ndarray] | None:
    """The side instances (``own``, cut to the window) of one region that a seam of the
    table's colour keeps apart: two instances of ``min_piece_px`` each whose seam (the
    region's pixels within ``band_px`` of both) is mostly table-coloured, and whose own
    median colours are both unlike the seam's, are apart where they touch (two instances
    of one blob) and the seam opens onto the table; every other pair is one part. Keys and
    grouped pixels as :func:`_gap_pieces` gives them (the key ``(0, id)``), None where
    fewer than two groups are left."""
    ids, sizes = np.unique(own[region], return_counts=True)
    ids = ids[(ids > 0) & (sizes >= min_piece_px)]
    if ids.size < 2:
        return None
    near = [cv2.distanceTransform((own != i).view(np.uint8), cv2.DIST_L2, 3) <= band_px
            for i in ids]
    outside = ~ndimage.binary_fill_holes(region)
    touching = [cv2.dilate((own == i).astype(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
                for i in ids]
    medians = [np.median(lab[region & (own == i)], axis=0) for i in ids]
    def together(a: int, b: int) -> bool:
        seam = region & near[a] & near[b]
        coloured = seam & table_like
        # two instances of one blob (apart ones are the fusion's own: apart_by_table)
        apart = np.any(seam & (own == ids[a]) & touching[b]) and \
            2 * np.count_nonzero(coloured) > np.count_nonzero(seam) and all(
            (np.abs(m - np.median(lab[coloured], axis=0)) > floors).any()
            for m in (medians[a], medians[b])) and _open_to_table(coloured, outside)
        return not apart

    root_of = pair_roots(ids.size, together)
    roots = sorted(set(root_of))
    if len(roots) < 2:
        return None
    grouped = np.zeros(region.shape, np.int32)
    for a in range(ids.size):
        grouped[region & (own == ids[a])] = roots.index(root_of[a]) + 1
    fill_from_nearest(grouped, region & (grouped == 0))
    grouped[~region] = 0
    return [(0, int(ids[r])) for r in roots], grouped


def _open_to_table(gap: np.ndarray, outside: np.ndarray) -> bool:
    """Whether a gap's pixels reach the table outside the region (``outside``: beyond its
    outline, holes filled): a gap between two parts opens onto the table at its ends, a slot
    or a hole through one part is closed by the part around it."""
    reach = cv2.dilate(gap.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
    return bool(np.any(reach & outside))


def _holder(ids: np.ndarray, size: int) -> int:
    """The id that holds a third of a piece of ``size`` px (``ids``: its pixels'), else 0."""
    ids = ids[ids > 0]
    if not ids.size:
        return 0
    best = int(np.bincount(ids).argmax())
    return best if 3 * np.count_nonzero(ids == best) >= size else 0


__all__ = ['apart_by_gap_colour']
