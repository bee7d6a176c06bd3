"""Foreground -> instances: the marker-controlled watershed and touching-object separation.

* **Watershed.** The union of the cues gives markers (sure object = union cores, sure
  background = pixels far from every candidate); ``cv2.watershed`` floods between them.
  OpenCV floods the largest absolute neighbour difference of its input; we feed it the image
  smoothed by the 3x3 binomial kernel, so the flooded relief is the 3x3 Sobel gradient
  magnitude (Sobel = binomial smoothing followed by a central difference).
* **Instances.** Connected components, small-blob removal (``min_area_px``) and touching-object
  separation: with depth, a blob whose solid pixels (valid depth above the table, off range
  jumps) form several large pieces is divided between them first (the seam of two touching
  parts, or an occluding contour, breaks the surface); a blob of several materials is
  divided by colour (2-means on chroma); the distance transform of a blob is cut at a
  fraction of its maximum; two or more cores seed a second watershed that divides the blob
  (each division of one blob: :mod:`~tlessbot_ros.core.localise.blob_split`).

Labels are (H, W) uint16 with 0 = background. Boxes are (x, y, w, h) int32 pixels, the usual
OpenCV / BOP ``bbox`` convention.
"""
from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from typing import cast

import cv2
import numpy as np

from tlessbot_ros.core.common import label_boxes
from tlessbot_ros.core.localise.blob_split import (
    colour_pieces,
    depth_pieces,
    split_at_distance_cores,
    watershed_padded,
)
from tlessbot_ros.core.localise.cues import Surfaces, depth_cue
from tlessbot_ros.core.localise.lightness import lightness_pieces
from tlessbot_ros.core.localise.params import SegmentationParams
from tlessbot_ros.core.localise.part_scale import join_pieces_no_part_fits, several_parts
from tlessbot_ros.core.localise.thin import is_thin, region_pieces


# --------------------------------------------------------------------------- watershed
def watershed_refine(rgb: np.ndarray, candidate: np.ndarray, sure: np.ndarray, *,
                     band_px: int = 4, sure_background: np.ndarray | None = None) -> np.ndarray:
    """Marker-controlled watershed between sure-object and sure-background markers.

    Args:
        rgb: (H, W, 3) uint8 image to flood (smoothed here by the 3x3 binomial kernel so the
            relief is the Sobel gradient magnitude).
        candidate: (H, W) bool object candidates; pixels further than ``band_px`` from any
            candidate are sure background.
        sure: (H, W) bool sure-object pixels (markers).
        sure_background: optional (H, W) bool pixels known to be table (e.g. from depth);
            they become background markers too (sure-object pixels win where both hold).

    Returns:
        (H, W) bool object mask.
    """
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_px + 1, 2 * band_px + 1))
    out = np.zeros(candidate.shape, bool)
    if not sure.any():
        return out
    # The dilation reaches band_px from a candidate: made in the candidates' box grown by
    # that much (all of its non-zero pixels, the values the whole image gives there).
    H, W = candidate.shape
    bx, by, bw, bh = cv2.boundingRect(np.ascontiguousarray(candidate).view(np.uint8))
    y0, x0 = max(by - band_px, 0), max(bx - band_px, 0)
    y1, x1 = min(by + bh + band_px, H), min(bx + bw + band_px, W)
    near = np.zeros((H, W), np.uint8)
    if bw and bh:
        near[y0:y1, x0:x1] = cv2.dilate(
            np.ascontiguousarray(candidate[y0:y1, x0:x1]).view(np.uint8), kernel)
    # Flood only the box around the candidates (the rest is background anyway).
    x, y, w, h = cv2.boundingRect(near[y0:y1, x0:x1])
    x, y = x + x0, y + y0
    near_c = near[y:y + h, x:x + w].astype(bool)
    markers = np.zeros((h, w), np.int32)
    markers[~near_c] = 1
    if sure_background is not None:
        markers[sure_background[y:y + h, x:x + w]] = 1
    markers[sure[y:y + h, x:x + w]] = 2
    smooth = cv2.GaussianBlur(rgb[y:y + h, x:x + w], (3, 3), 0)
    markers = watershed_padded(smooth, markers)
    # Watershed lines (-1) lie on the edge itself; they go to the background.
    out[y:y + h, x:x + w] = markers == 2
    return out


# --------------------------------------------------------------------------- instances
def split_touching(mask: np.ndarray, rgb: np.ndarray | None = None, *,
                   height_m: np.ndarray | None = None, depth_m: np.ndarray | None = None,
                   params: SegmentationParams = SegmentationParams()) -> np.ndarray:
    """Label a foreground mask, dividing blobs that hold several parts.

    With depth (``height_m`` and ``depth_m``, and ``depth_split_jump`` > 0), a blob whose
    solid pixels (valid depth above the table, off range jumps) form two or more
    4-connected pieces of at least ``depth_split_min_px`` pixels is first divided by a
    watershed seeded with them, where the depth confirms the seam (see
    :func:`~tlessbot_ros.core.localise.blob_split.depth_pieces`); blobs (or pieces) of
    several materials are then divided by colour (2-means on a / L, b / L); last, a blob
    whose distance transform, cut at ``split_core_fraction`` of its maximum, has two or
    more cores is divided by a watershed seeded with them.

    Args:
        mask: (H, W) bool foreground.
        rgb: (H, W, 3) uint8 image; when given, the dividing lines follow its colour edges.
        height_m: (H, W) float height above the table in metres, NaN = invalid
            (:func:`~tlessbot_ros.core.localise.height_above_table`).
        depth_m: (H, W) float depth of the same pixels in metres, 0 or NaN = invalid.

    Returns:
        (H, W) int32 labels, 0 = background, 1..N (blobs below ``min_area_px`` removed).
    """
    surfaces = None
    if height_m is not None or depth_m is not None:
        if height_m is None or depth_m is None:
            raise ValueError('the depth split needs both height_m and depth_m')
        if np.shape(height_m) != np.shape(mask) or np.shape(depth_m) != np.shape(mask):
            raise ValueError(f'height_m {np.shape(height_m)} and depth_m {np.shape(depth_m)} '
                             f'must have the shape of the mask, {np.shape(mask)}')
        if params.depth_split_jump > 0:
            depth = np.nan_to_num(np.asarray(depth_m, np.float32), nan=0.0, posinf=0.0)
            surfaces = depth_cue(np.asarray(height_m, np.float32), params,
                                  depth=depth).surfaces
    return _instances(mask, rgb, params, surfaces,
                      None if height_m is None else np.asarray(height_m, np.float32))[0]


def _instances(mask: np.ndarray, rgb: np.ndarray | None, params: SegmentationParams,
               surfaces: Surfaces | None = None, height_m: np.ndarray | None = None,
               thin_regions: np.ndarray | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(labels (H, W) int32, boxes (N, 4) int32, areas (N,) int64, depth groups (N,) int32)
    of :func:`split_touching`; the instances cut from one piece of a depth split share a
    group id > 0 (0: not divided by depth). With ``height_m`` (the mask's scale) a thin
    blob is kept whole (:func:`~tlessbot_ros.core.localise.thin.is_thin`), and so is a
    thin part's lifted colour region in a blob (``thin_regions``, the mask's scale,
    :func:`~tlessbot_ros.core.localise.thin.thin_lift`).

    Blobs are labelled by one look-up; only blobs that may hold several parts (deep enough
    for a split) are looked at one by one, in a crop.
    """
    mask_u8 = np.ascontiguousarray(mask, dtype=np.uint8)
    n, comp, stats, _ = cv2.connectedComponentsWithStats(mask_u8, connectivity=8,
                                                         ltype=cv2.CV_32S)
    big = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= params.min_area_px) + 1
    H, W = mask.shape
    # pieces[i]: the blob's pieces (y0, x0, [(bool mask in the crop, depth group)]);
    # absent: the blob stays whole.
    pieces: dict[int, tuple[int, int, list[tuple[np.ndarray, int]]]] = {}
    n_groups, n_lightness = 0, LIGHTNESS_GROUPS
    # A blob narrower than twice the smallest split depth has a distance transform below it.
    deep = 2.0 * params.split_min_depth_px
    for i in big if params.split_touching else ():
        x, y, w, h, area = (int(v) for v in stats[i])
        if min(w, h) < deep:
            continue
        x0, y0 = max(x - 1, 0), max(y - 1, 0)
        x1, y1 = min(x + w + 1, W), min(y + h + 1, H)
        window = np.s_[y0:y1, x0:x1]
        blob = comp[window] == i
        found, n_groups, n_lightness = _blob_pieces(
            blob, window, rgb, params, surfaces, height_m,
            None if thin_regions is None else thin_regions[window], (n_groups, n_lightness))
        if len(found) > 1:
            pieces[int(i)] = (y0, x0, [(f, g) for f, g in found
                                       if cv2.countNonZero(f.view(np.uint8))
                                       >= params.min_area_px])
    lut = np.zeros(n, np.int32)
    boxes: list[tuple[int, int, int, int]] = []
    areas: list[int] = []
    groups: list[int] = []
    placed: list[tuple[int, int, np.ndarray, int]] = []
    for i in big:
        label = int(i)
        if label not in pieces:
            boxes.append(cast(tuple[int, int, int, int],
                              tuple(int(v) for v in stats[label, :4])))
            areas.append(int(stats[label, cv2.CC_STAT_AREA]))
            groups.append(0)
            lut[label] = len(boxes)
            continue
        y0, x0, found = pieces[label]
        for f, g in found:
            bx, by, bw, bh = cv2.boundingRect(f.view(np.uint8))
            boxes.append((bx + x0, by + y0, bw, bh))
            areas.append(cv2.countNonZero(f.view(np.uint8)))
            groups.append(g)
            placed.append((y0, x0, f, len(boxes)))
    labels = lut[comp]
    for y0, x0, f, k in placed:
        labels[y0:y0 + f.shape[0], x0:x0 + f.shape[1]][f] = k
    return (labels, np.array(boxes, np.int32).reshape(-1, 4),
            np.array(areas, np.int64), np.array(groups, np.int32))


def _blob_pieces(blob: np.ndarray, window: tuple[slice, slice], rgb: np.ndarray | None,
                 params: SegmentationParams, surfaces: Surfaces | None,
                 height_m: np.ndarray | None, thin_regions: np.ndarray | None,
                 used: tuple[int, int]) -> tuple[list[tuple[np.ndarray, int]], int, int]:
    """One blob (a crop's mask at ``window`` of the image) divided by :func:`split_touching`'s
    steps: its pieces with their depth groups, and the depth and lightness groups used so far
    (``used`` before). A thin part's lifted colour region in a blob that is not thin as a
    whole (``thin_regions``, the crop's labels) is a piece of its own, kept whole as a thin
    blob is (:func:`~.thin.region_pieces`): the blob's distance cores would cut across it
    where a taller part touches it. The rest is divided piece by piece."""
    n_groups, n_lightness = used
    origin = (window[0].start or 0, window[1].start or 0)
    crop = None if rgb is None else rgb[window]
    depth_crop = None if surfaces is None else surfaces.depth_m[window]
    # a thin part: its holes and lobes are no seams, its depth too noisy; colour still is
    thin = is_thin(blob, height_m, origin, params)
    regions, rests = ([], []) if thin or thin_regions is None else \
        region_pieces(blob, thin_regions, params)
    found: list[tuple[np.ndarray, int]] = []
    if regions:
        found, n_groups = _cores_of_pieces(regions, crop, True, depth_crop, params, 0, n_groups)
    for rest, rest_thin in [(piece, is_thin(piece, height_m, origin, params))
                            for piece in rests] if regions else [(blob, thin)]:
        by_depth, ties = ([rest], [0]) if surfaces is None or rest_thin else \
            depth_pieces(rest, Surfaces(*(a[window] for a in (
                surfaces.solid, surfaces.table, surfaces.depth_m))), crop, params)
        for depth_piece, tie in zip(by_depth, ties):
            group = 0
            if len(set(ties)) > 1:   # pieces told apart by no seam share their group
                group = n_groups + 1 + tie
            more, n_groups, n_lightness = _pieces_of_depth_piece(
                depth_piece, crop, rest_thin, depth_crop, params, group,
                (n_groups, n_lightness))
            found += more
        n_groups += len(by_depth) if len(set(ties)) > 1 else 0
    return found, n_groups, n_lightness


def _pieces_of_depth_piece(piece: np.ndarray, crop: np.ndarray | None, thin: bool,
                           depth_m: np.ndarray | None, params: SegmentationParams, group: int,
                           used: tuple[int, int]
                           ) -> tuple[list[tuple[np.ndarray, int]], int, int]:
    """One piece of a depth split (or a blob whole; a crop's mask) divided by colour, by
    lightness and at its distance cores, each with its depth group, and the depth and
    lightness groups used so far (``used`` before). ``depth_m``: the crop's depth, in the view
    split by depth (the side one), else None."""
    n_groups, n_lightness = used
    by_colour = [piece] if crop is None or params.colour_split_delta <= 0 else \
        colour_pieces(piece, crop, params)
    if depth_m is not None:   # (the side view: the top one sees thin parts small)
        by_colour = join_pieces_no_part_fits(by_colour, params)
    by_lightness, n_lightness = _by_lightness(by_colour, crop, params, group, n_lightness)
    found: list[tuple[np.ndarray, int]] = []
    for part, part_group in by_lightness:
        more, n_groups = _cores_of_pieces([part], crop, thin, depth_m, params, part_group,
                                          n_groups)
        found += more
    return found, n_groups, n_lightness


def _by_lightness(pieces: list[np.ndarray], crop: np.ndarray | None,
                  params: SegmentationParams, group: int, first_group: int
                  ) -> tuple[list[tuple[np.ndarray, int]], int]:
    """The pieces of a blob (a crop's masks) each with its depth group ``group``, those of
    two lightnesses divided (:func:`~tlessbot_ros.core.localise.lightness.lightness_pieces`)
    into halves that are each a group of its own, from ``first_group`` on: the two-view
    fusion keeps them apart as it keeps a depth split (the top view, which sees both parts
    as one blob, would join them again). Returns them and the next free group."""
    out: list[tuple[np.ndarray, int]] = []
    for piece in pieces:
        halves = [piece] if crop is None else lightness_pieces(piece, crop, params)
        if len(halves) == 1:
            out.append((piece, group))
            continue
        for half in halves:
            out.append((half, first_group))
            first_group += 1
    return out, first_group


# The lightness halves' groups start here, past any depth split's of one image.
LIGHTNESS_GROUPS = 1 << 20


def _cores_of_pieces(pieces: list[np.ndarray], crop: np.ndarray | None, thin: bool,
                     depth_m: np.ndarray | None, params: SegmentationParams, group: int,
                     n_groups: int) -> tuple[list[tuple[np.ndarray, int]], int]:
    """The pieces of a blob (a crop's masks) divided at their distance cores, with depth
    groups, and the groups used so far. A thin piece stays whole unless larger than any
    part can look at its depth (``depth_m``, :func:`.part_scale.several_parts`): then it is
    divided too, each part a group of its own (the fusion keeps them apart)."""
    found: list[tuple[np.ndarray, int]] = []
    for piece in pieces:
        several = thin and depth_m is not None and several_parts(piece, depth_m, params)
        parts = piece.astype(np.int32) if thin and not several else \
            split_at_distance_cores(piece, crop, params)
        count = int(parts.max())
        if several and count > 1:
            found += [(parts == k, n_groups + k) for k in range(1, count + 1)]
            n_groups += count
        else:
            found += [(parts == k, group) for k in range(1, count + 1)]
    return found, n_groups


def instances_at_scale(foreground: np.ndarray, rgb: np.ndarray, small: np.ndarray,
                        params: SegmentationParams, surfaces: Surfaces | None = None,
                        height_m: np.ndarray | None = None,
                        thin_regions: np.ndarray | None = None
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Instance separation at the cue scale, labels carried back to the full-resolution mask.

    The blobs are divided on the ``small`` image (4x fewer pixels at half scale; the sizes in
    ``params`` are scaled with it; ``surfaces``, from the depth cue, are at that scale);
    every full-resolution foreground pixel then takes the label of its low-resolution pixel,
    or of a neighbour on the thin rim that the reduction lost. Returns uint16 labels, (N, 4)
    int32 boxes, (N,) int64 areas at full resolution and (N,) int32 depth groups
    (:func:`_instances`).
    """
    h, w = small.shape[:2]
    H, W = foreground.shape
    if (h, w) == (H, W):
        labels, boxes, areas, groups = _instances(foreground, rgb, params, surfaces, height_m,
                                                  thin_regions)
        return labels.astype(np.uint16), boxes, areas, groups
    s = h / H
    small_params = _scaled_params(params, s)
    fg_small = cv2.resize(foreground.view(np.uint8) * np.uint8(255), (w, h),
                          interpolation=cv2.INTER_AREA) >= 128
    labels_s, boxes_s, _, groups = _instances(fg_small, small, small_params, surfaces, height_m,
                                              thin_regions)
    labels_s = labels_s.astype(np.uint16)
    n = len(boxes_s)
    if n == 0:
        return (np.zeros((H, W), np.uint16), np.zeros((0, 4), np.int32), np.zeros(0, np.int64),
                np.zeros(0, np.int32))
    up = cv2.resize(labels_s, (W, H), interpolation=cv2.INTER_NEAREST)
    labels = np.zeros((H, W), np.uint16)
    # Only the foreground's box can be labelled; with 2 more pixels around it the 5x5 dilation
    # of the rim reads what it reads in the whole image (beyond the image's edge: nothing).
    bx, by, bw, bh = cv2.boundingRect(np.ascontiguousarray(foreground).view(np.uint8))
    y0, y1, x0, x1 = max(by - 2, 0), min(by + bh + 2, H), max(bx - 2, 0), min(bx + bw + 2, W)
    fg, up_box, out = foreground[y0:y1, x0:x1], up[y0:y1, x0:x1], labels[y0:y1, x0:x1]
    out[fg] = up_box[fg]
    rim = fg & (up_box == 0)
    if rim.any():
        grown = cv2.dilate(np.ascontiguousarray(up_box), np.ones((5, 5), np.uint8))
        out[rim] = grown[rim]
    # Boxes and areas: look only near each low-resolution box.
    boxes = np.zeros((n, 4), np.int32)
    areas = np.zeros(n, np.int64)
    pad = int(np.ceil(1.0 / s)) + 2
    for k, (bx, by, bw, bh) in enumerate(boxes_s, start=1):
        y0, y1 = max(int(by / s) - pad, 0), min(int((by + bh) / s) + pad, H)
        x0, x1 = max(int(bx / s) - pad, 0), min(int((bx + bw) / s) + pad, W)
        m = (labels[y0:y1, x0:x1] == k).view(np.uint8)
        bx, by, bw, bh = cv2.boundingRect(m)
        boxes[k - 1] = (bx + x0, by + y0, bw, bh)
        areas[k - 1] = cv2.countNonZero(m)
    if np.any(areas == 0):
        labels = relabel_sequential(labels)
        keep = areas > 0
        boxes, areas, groups = boxes[keep], areas[keep], groups[keep]
    return labels, boxes, areas, groups


@lru_cache(maxsize=8)
def _scaled_params(params: SegmentationParams, s: float) -> SegmentationParams:
    """``params`` with its sizes for an image scaled by ``s`` (made once per settings: the
    dataclass's checks would otherwise run on every frame)."""
    whole = None if params.whole_parts is None else \
        tuple((a, px * s * s, look * s) for a, px, look in params.whole_parts)
    largest = None if params.largest_part_px_m2 is None else params.largest_part_px_m2 * s * s
    return replace(params, min_area_px=max(1, int(round(params.min_area_px * s * s))),
                   whole_parts=whole, largest_part_px_m2=largest,
                   split_min_depth_px=params.split_min_depth_px * s,
                   split_min_core_px=max(1, int(round(params.split_min_core_px * s * s))),
                   depth_split_min_px=max(1, int(round(params.depth_split_min_px * s * s))))


def boxes_from_labels(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y, w, h) int32 boxes (N, 4) and int64 areas (N,) of labels 1..N (empty ids: zeros)."""
    counts, boxes = label_boxes(labels)
    return boxes[1:], counts[1:]


def relabel_sequential(labels: np.ndarray) -> np.ndarray:
    """Renumber labels to 1..N in order of first appearance id; returns uint16."""
    ids = np.unique(labels)
    ids = ids[ids > 0]
    lut = np.zeros(int(labels.max()) + 1 if labels.size else 1, np.uint16)
    lut[ids] = np.arange(1, ids.size + 1, dtype=np.uint16)
    return cast(np.ndarray, lut[labels])


