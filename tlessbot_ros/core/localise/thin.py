"""Thin parts in the localiser: blobs whose top is a few millimetres above the table.

A plate, a bracket or a spanner 3-6 mm thick rises above the table by little more than the
depth noise (a D415 at 0.6-0.9 m: 1-2 mm), so depth alone neither finds it whole nor tells
where two of them touch: the solid pixels of one part fall into several pieces, and the
distance transform of an outline with holes, slots and lobes has several cores. Both splits
of :func:`~tlessbot_ros.core.localise.split_touching` would cut one thin part into fragments
(on simulated flat parts: 17 fragments in 6 frames, each a false positive and a part missed).
:func:`is_thin` marks such blobs, which are then kept whole: their outline comes from the
colour cues, confirmed by the few millimetres the depth does see. The two-view fusion keeps a
side blob that is one thin part whole too (the top camera, farther away, breaks thin parts
up more often than it separates them).

Where the depth's noise reaches the part's own height (a stereo camera's smoothed depth on a
strip a few millimetres thick; docs/bench/smoothed-parts-missed.md), many of the part's
pixels read as table, and the depth's veto would cut its colour blob into pieces or remove it.
:func:`raised_thin_blobs` finds the colour blobs that are thin parts standing clear of the
table as a whole (their median height), which the veto then leaves alone.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from tlessbot_ros.core.localise.colour_edge import common_colours
from tlessbot_ros.core.localise.cues import eroded, opened
from tlessbot_ros.core.localise.params import SegmentationParams
from tlessbot_ros.core.localise.part_scale import could_be_whole, shared_border_ratio

# A colour region holds fewer pixels than its blob, and a patch of the table's noise that size
# can rise as high as a thin part: a region is lifted only where its median height stands
# this many of the table's noise deviations above it too.
REGION_CLEAR_K = 1.0


def is_thin(blob: np.ndarray, height_m: np.ndarray | None, origin: tuple[int, int],
            params: SegmentationParams) -> bool:
    """Whether a blob is a thin part (kept whole by the instance separation).

    Args:
        blob: (h, w) bool, the blob in a crop of the view.
        height_m: the view's (H, W) float height above the table (metres, NaN = invalid) at
            the same scale, or None (no depth: never thin).
        origin: (row, column) of the crop's corner in ``height_m``.
        params: ``thin_max_height_m`` (0: never thin) and ``thin_min_valid``.

    Returns:
        True when at least ``thin_min_valid`` of the blob's pixels have depth and the
        ``thin_quantile`` of their heights is below ``thin_max_height_m``.
    """
    if height_m is None or params.thin_max_height_m <= 0:
        return False
    y0, x0 = origin
    heights = height_m[y0:y0 + blob.shape[0], x0:x0 + blob.shape[1]][blob]
    heights = heights[np.isfinite(heights)]
    if heights.size < max(1, params.thin_min_valid * np.count_nonzero(blob)):
        return False
    return float(np.quantile(heights, params.thin_quantile)) < params.thin_max_height_m


def thin_instances(labels: np.ndarray, height_m: np.ndarray | None,
                   params: SegmentationParams) -> np.ndarray:
    """(N,) bool: which of the instances 1..N of a (H, W) label image are thin (:func:`is_thin`
    on ``height_m``, a (h, w) height map of the same view at any scale; all False without)."""
    n = int(labels.max(initial=0))
    if height_m is None or n == 0 or params.thin_max_height_m <= 0:
        return np.zeros(n, bool)
    h, w = height_m.shape
    small = cv2.resize(np.ascontiguousarray(labels, np.uint16), (w, h),
                       interpolation=cv2.INTER_NEAREST)
    return np.array([is_thin(small == k, height_m, (0, 0), params) for k in range(1, n + 1)])



def raised_thin_blobs(candidate: np.ndarray, height_m: np.ndarray | None,
                      table: np.ndarray, params: SegmentationParams, *,
                      noise_m: float = 0.0, lab: np.ndarray | None = None) -> np.ndarray:
    """(h, w) bool: the pixels where the depth's veto is lifted (:func:`thin_lift`'s first
    answer)."""
    return thin_lift(candidate, height_m, table, params, noise_m=noise_m, lab=lab)[0]


def thin_lift(candidate: np.ndarray, height_m: np.ndarray | None, table: np.ndarray,
              params: SegmentationParams, *, noise_m: float = 0.0,
              lab: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """((h, w) bool, (h, w) int32): the pixels where the depth's veto is lifted, and the
    colour regions lifted (labels 1..N, 0 elsewhere; see ``lab``), each the outline of one thin
    part that the instance separation keeps (:func:`region_pieces`). Lifted: the 8-connected
    blobs of ``candidate`` that are thin parts raised above the table as a whole, but for their rim
    (one pixel, 4-connected: the table around a small part stays out of its mask). Raised: thin
    (:func:`is_thin`'s test) and their median valid height at least ``thin_lift_height_m``,
    where the table pixels take ``thin_lift_min_share`` of its inside (less: the depth
    resolves it), unless they divide the blob into two pieces that could each be a part (two
    thin parts touching: the gap between them is table); all False without depth or with
    either rule off. A raised blob's pixels that read more than ``thin_lift_resolved_k``
    deviations ``noise_m`` below its median are left out too: the depth tells them from the
    part's top.

    One pixel's height cannot tell a thin part from the table where the noise is as high as
    the part; the median of a blob's hundreds of pixels can (a table-coloured piece or a cast
    shadow reads about 0; a blob holding a taller part is not thin). Where the part stands
    clear of the noise (a nut 6 mm high on a per-pixel depth), a pixel reading far below it
    is not the part's top: the bore or the table seen past its edge, which would move the
    outline the pose is fitted to.

    Args:
        candidate: (h, w) bool colour candidates at ``params.cue_scale``, before the veto.
        height_m: (h, w) float height above the table (metres, NaN = invalid), or None.
        table: (h, w) bool the depth's table pixels (the veto).
        params: ``thin_lift_height_m``, ``thin_lift_min_share``, ``thin_lift_resolved_k``,
            ``thin_max_height_m``, ``thin_quantile``, ``thin_min_valid``; ``whole_parts``,
            ``min_area_px`` and ``cue_scale`` for the pieces.
        noise_m: the table's robust height deviation (m; ``DepthCue.sigma_m``), 0: unknown
            (no pixel is resolved).
        lab: (h, w, 3) float LAB image at the cue scale, or None: a blob that is not raised
            as a whole is tested again per colour region (:func:`colour_regions`, steps within
            ``thin_lift_colour_floors`` x (``grey_floor``, ``lab_floor``, ``lab_floor``)) of
            its pixels below ``thin_max_height_m``: the thin part alone, without a taller
            part or a thin one of another colour beside it, or a patterned table around it. A
            region whose median colour lies within ``thin_lift_table_floors`` floors of one of
            the table's common colours (:func:`~.colour_edge.common_colours`) is table; one
            whose median height is under ``REGION_CLEAR_K`` x ``noise_m`` is noise; one that
            would join two parts is not lifted (``thin_region_no_bridge``,
            :func:`_bridges_parts`).
    """
    regions = np.zeros(candidate.shape, np.int32)
    if height_m is None or params.thin_lift_height_m <= 0 or params.thin_max_height_m <= 0:
        return np.zeros(candidate.shape, bool), regions
    count, labels = cv2.connectedComponents(candidate.view(np.uint8), connectivity=8)
    if count <= 1:
        return np.zeros(candidate.shape, bool), regions
    raised, medians = _raised(labels, count, height_m, table, params)
    lifted = _lifted(labels, raised, medians, height_m, table, params, noise_m)
    if lab is not None and params.thin_lift_colour_floors > 0:
        rest = (labels > 0) & ~raised[labels] & \
            ~(np.nan_to_num(height_m, nan=0.0) >= params.thin_max_height_m)
        floors = params.thin_lift_colour_floors * np.array(
            [params.grey_floor, params.lab_floor, params.lab_floor], np.float32)
        units = colour_regions(rest, lab, floors)
        n_units = int(units.max(initial=0)) + 1
        if n_units > 1:
            raised, medians = _raised(units, n_units, height_m, table, params)
            raised &= medians >= REGION_CLEAR_K * noise_m
            near = params.thin_lift_table_floors * floors[None] / params.thin_lift_colour_floors
            table_colours = common_colours(lab, table, floors)
            candidates = np.flatnonzero(raised)
            if len(candidates):   # a piece of the table is of its colours
                colours = np.stack([ndimage.median(lab[..., c], labels=units, index=candidates)
                                    for c in range(3)], axis=1)
                raised[candidates] = ~np.any(np.all(
                    np.abs(table_colours[None] - colours[:, None]) <= near, axis=2), axis=1)
            if params.thin_region_no_bridge:
                raised &= ~_bridges_parts(units, raised, candidate & ~table, params)
            lifted |= _lifted(units, raised, medians, height_m, table, params, noise_m)
            kept = np.flatnonzero(raised)
            numbers = np.zeros(n_units, np.int32)
            numbers[kept] = np.arange(1, len(kept) + 1)
            regions = numbers[units]
    return lifted, regions


def region_pieces(blob: np.ndarray, regions: np.ndarray, params: SegmentationParams
                  ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """A blob's lifted colour regions that are parts of their own, and the rest of the blob
    in pieces ((h, w) bool masks of the blob's crop; both empty where no region is).

    A region (:func:`thin_lift`'s labels ``regions`` cut to the crop) holding at least
    ``min_area_px`` of the blob is one; the rest, less the regions and opened by one pixel
    (the colour outline and the foreground's differ by about that), falls into pieces of at
    least ``min_area_px``. A region that meets one of them along
    ``thin_region_cut_border`` or more (:func:`~.part_scale.shared_border_ratio`) is no part
    of its own: the thin flange of a taller part (a bracket lying on its side), which meets
    the rest across its whole width, where a part beside another meets it along a short
    stretch.
    """
    ids, counts = np.unique(regions[blob], return_counts=True)
    kept = [blob & (regions == k) for k, n in zip(ids, counts)
            if k > 0 and n >= params.min_area_px]
    rests: list[np.ndarray] = []
    while kept:
        rest = opened(blob & ~np.logical_or.reduce(kept), 1)
        count, labels = cv2.connectedComponents(rest.view(np.uint8), connectivity=8)
        rests = [piece for piece in (labels == k for k in range(1, count))
                 if np.count_nonzero(piece) >= params.min_area_px]
        apart = [r for r in kept if all(shared_border_ratio(r, piece) <
                                        params.thin_region_cut_border for piece in rests)]
        if len(apart) == len(kept):
            break
        kept = apart
    return kept, rests if kept else []


def colour_regions(mask: np.ndarray, lab: np.ndarray, floors: np.ndarray) -> np.ndarray:
    """(h, w) int32 labels 1..N (0 outside ``mask``): the regions of ``mask`` whose pixels are
    linked through 8-neighbours whose every LAB channel differs by at most ``floors`` ((3,)),
    so that a region grows along a part's smooth shading and stops at its outline.

    Args:
        mask: (h, w) bool.
        lab: (h, w, 3) float LAB image of the same scale.
        floors: (3,) the largest step between neighbours (L, a, b).
    """
    h, w = mask.shape
    index = np.arange(h * w).reshape(h, w)
    lab = np.asarray(lab, np.float32)
    starts, ends = [], []
    for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):
        a = np.s_[0:h - dy, max(0, -dx):w - max(0, dx)]
        b = np.s_[dy:h, max(0, dx):w + min(0, dx)]
        linked = mask[a] & mask[b] & np.all(np.abs(lab[a] - lab[b]) <= floors, axis=2)
        starts.append(index[a][linked])
        ends.append(index[b][linked])
    first, second = np.concatenate(starts), np.concatenate(ends)
    graph = coo_matrix((np.ones(len(first), np.int8), (first, second)), shape=(h * w, h * w))
    _, regions = connected_components(graph, directed=False)
    # renumber the regions that hold a mask pixel 1..N
    _, dense = np.unique(regions[mask.ravel()], return_inverse=True)
    labels = np.zeros(h * w, np.int32)
    labels[mask.ravel()] = dense.ravel() + 1
    return labels.reshape(h, w)


def _raised(labels: np.ndarray, count: int, height_m: np.ndarray, table: np.ndarray,
            params: SegmentationParams) -> tuple[np.ndarray, np.ndarray]:
    """((count,) bool: which blobs 1..count-1 of ``labels`` are raised thin parts, the test of
    :func:`raised_thin_blobs`; (count,) float their lower median valid heights, m)."""
    flat, heights = labels.ravel(), height_m.ravel()
    valid = (flat > 0) & np.isfinite(heights)
    order = np.lexsort((heights[valid], flat[valid]))
    blob, sorted_heights = flat[valid][order], heights[valid][order]
    n_valid = np.bincount(blob, minlength=count)
    n_pixels = np.bincount(flat, minlength=count)
    starts = np.cumsum(n_valid) - n_valid

    def quantile(q: float) -> np.ndarray:
        at = starts + np.floor(q * np.maximum(n_valid - 1, 0)).astype(np.int64)
        picked: np.ndarray = sorted_heights[np.clip(at, 0, max(len(sorted_heights) - 1, 0))]
        return picked

    if not len(sorted_heights):
        return np.zeros(count, bool), np.zeros(count)
    raised = (n_valid > 0) & (n_valid >= params.thin_min_valid * n_pixels) & \
        (quantile(0.5) >= params.thin_lift_height_m) & \
        (quantile(params.thin_quantile) < params.thin_max_height_m)
    raised[0] = False
    for k in np.flatnonzero(raised):   # where the veto takes little, the depth resolves it
        blob = labels == k
        inside = cv2.erode(blob.view(np.uint8), np.ones((3, 3), np.uint8)).view(bool)
        raised[k] = np.count_nonzero(table & inside) >= \
            params.thin_lift_min_share * max(int(np.count_nonzero(inside)), 1) and \
            not _divided_into_parts(blob, table, params)
    return raised, quantile(0.5)


def _lifted(labels: np.ndarray, raised: np.ndarray, medians: np.ndarray,
            height_m: np.ndarray, table: np.ndarray, params: SegmentationParams,
            noise_m: float) -> np.ndarray:
    """(h, w) bool: the ``raised`` blobs of ``labels`` but for their rim and their pixels the
    depth resolves below them (:func:`_resolved_below`)."""
    resolved = _resolved_below(labels, medians, height_m, table, params, noise_m)
    lifted: np.ndarray = eroded(raised[labels], 1) & ~resolved
    return lifted


def _resolved_below(labels: np.ndarray, medians: np.ndarray, height_m: np.ndarray,
                    table: np.ndarray, params: SegmentationParams, noise_m: float
                    ) -> np.ndarray:
    """(h, w) bool: the ``table`` pixels of the blobs ``labels`` (1..N) whose height reads
    more than ``thin_lift_resolved_k`` x ``noise_m`` below their blob's median ``medians[k]``
    (none where either is 0)."""
    reach = params.thin_lift_resolved_k * noise_m
    if reach <= 0:
        return np.zeros(labels.shape, bool)
    with np.errstate(invalid='ignore'):
        below: np.ndarray = table & (labels > 0) & (height_m < medians[labels] - reach)
    return below


def _divided_into_parts(blob: np.ndarray, table: np.ndarray, params: SegmentationParams
                        ) -> bool:
    """Whether ``table`` leaves two or more pieces of ``blob`` (cue scale) that could each be
    a whole part (:func:`_whole_pieces`)."""
    rows, cols = np.nonzero(blob)
    window = np.s_[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
    return int(np.count_nonzero(_whole_pieces(blob[window] & ~table[window], params)[0])) >= 2


def _whole_pieces(mask: np.ndarray, params: SegmentationParams
                  ) -> tuple[np.ndarray, np.ndarray]:
    """The 8-connected pieces of ``mask`` ((h, w) bool, cue scale): ((count,) bool, which
    could each be a whole part at full resolution (:func:`~tlessbot_ros.core.localise.
    part_scale.could_be_whole`, at least ``min_area_px``); (h, w) int32 their labels)."""
    count, pieces = cv2.connectedComponents(mask.view(np.uint8), connectivity=8)
    up = 1.0 / params.cue_scale
    sizes = np.bincount(pieces.ravel(), minlength=count) * up * up
    whole = np.zeros(count, bool)
    for k in np.flatnonzero(sizes >= 0.5 * params.min_area_px):   # (upscaled: about)
        if k == 0:
            continue
        rows, cols = np.nonzero(pieces == k)
        crop = pieces[rows.min():rows.max() + 1, cols.min():cols.max() + 1] == k
        piece = cv2.resize(crop.view(np.uint8), None, fx=up, fy=up,
                           interpolation=cv2.INTER_NEAREST) > 0
        whole[k] = np.count_nonzero(piece) >= params.min_area_px and \
            could_be_whole(piece, params)
    return whole, pieces


def _bridges_parts(units: np.ndarray, raised: np.ndarray, kept: np.ndarray,
                   params: SegmentationParams) -> np.ndarray:
    """(count,) bool: which ``raised`` colour regions of ``units`` (labels 1..count-1, cue
    scale) touch (8-neighbours) two or more pieces of ``kept`` (the candidates the veto leaves,
    less the raised regions) that could each be a whole part (:func:`_whole_pieces`): lifted,
    the region would join two parts into one blob, a part's low rim or the gap between two
    parts in a pile rather than a thin part of its own."""
    out = np.zeros(raised.shape, bool)
    if not raised.any():
        return out
    whole, pieces = _whole_pieces(kept & ~raised[units], params)
    if np.count_nonzero(whole) < 2:
        return out
    ring = np.ones((3, 3), np.uint8)
    for k in np.flatnonzero(raised):
        rows, cols = np.nonzero(units == k)
        window = np.s_[max(rows.min() - 1, 0):rows.max() + 2,
                       max(cols.min() - 1, 0):cols.max() + 2]
        near = cv2.dilate((units[window] == k).view(np.uint8), ring).view(bool)
        touched = np.unique(pieces[window][near])
        out[k] = np.count_nonzero(whole[touched]) >= 2
    return out
