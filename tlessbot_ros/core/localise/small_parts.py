"""The outline of a part a few pixels across, completed by the depth at the image's own
resolution.

The colour and depth cues are computed at the cue scale (half resolution by default), so a
blob's outline is known to one cue pixel: two image pixels. For a part 10 image pixels
across (an 8 mm nut at 0.64 m) that is a box one or two pixels too small or shifted on a
side, and a box 9 x 10 px one pixel off on each side already overlaps the part's by less
than 0.7. The blobs that only the parts' sizes admit
(``SegmentationParams.small_blob_candidates_px``, :mod:`.part_scale`) also take the
full-resolution depth pixels higher than the table (``table_height_m``: the height below
which the depth cue calls a pixel table) within one cue pixel of them: where the depth sees
the part beside the blob. The blob only grows (its holes filled): the depth of a part that
small misses pixels at its rim, and a region shrunk below the classifier's smallest seen
instance (``ClassifyParams.min_instance_px``) would lose its nearer view's vote.
"""
from __future__ import annotations

import cv2
import numpy as np

from tlessbot_ros.core.localise.colour import rgb_to_lab
from tlessbot_ros.core.localise.cues import height_above_table


def small_blobs_from_depth(labels: np.ndarray, boxes: np.ndarray, areas: np.ndarray,
                           depth_m: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray,
                           below_px: int, table_height_m: float, reach_px: int,
                           rgb: np.ndarray | None = None, floors: np.ndarray | None = None
                           ) -> tuple[np.ndarray, np.ndarray]:
    """Each instance of fewer than ``below_px`` pixels of ``labels`` ((H, W), changed in
    place) grown by the full-resolution pixels within ``reach_px`` of it (and of no other
    instance) whose depth lies higher than ``table_height_m`` above the table, in the
    pieces that touch it, its holes filled. An instance the depth calls table (none of its
    pixels higher, or fewer than half of those with depth: a shadow, a print) is left as
    it is. With ``rgb`` and ``floors`` (LAB), a pixel grown is not kept where it has the
    table's colour around it (:func:`table_coloured`): a smoothed (stereo-like) depth reads
    the table beside a part higher too.

    Returns:
        the (N, 4) boxes and (N,) areas of the instances, updated.
    """
    boxes, areas = boxes.copy(), areas.copy()
    H, W = labels.shape
    kernel = np.ones((2 * reach_px + 1, 2 * reach_px + 1), np.uint8)
    for k in np.flatnonzero((areas > 0) & (areas < below_px)):
        x, y, w, h = (int(v) for v in boxes[k])
        y0, y1 = max(y - reach_px, 0), min(y + h + reach_px, H)
        x0, x1 = max(x - reach_px, 0), min(x + w + reach_px, W)
        window = labels[y0:y1, x0:x1]
        blob = window == k + 1
        K_window = np.array(K, np.float64)
        K_window[0, 2] -= x0
        K_window[1, 2] -= y0
        height = height_above_table(depth_m[y0:y1, x0:x1], K_window, T_world_camera)
        valid = np.isfinite(height)
        high = valid & (height > table_height_m)
        near = cv2.dilate(blob.view(np.uint8), kernel).view(bool) & ((window == 0) | blob)
        seen = high & near
        on_part = np.count_nonzero(seen & blob)
        if on_part == 0 or 2 * on_part < np.count_nonzero(valid & blob):
            continue   # the depth calls it table (a shadow, a print): no guide to its outline
        # the blob and what the depth calls part beside it
        _, pieces = cv2.connectedComponents((seen | blob).view(np.uint8), connectivity=8)
        new = _filled(pieces == pieces[blob][0]) & ((window == 0) | blob)
        if rgb is not None and floors is not None:
            lab = rgb_to_lab(rgb[y0:y1, x0:x1]).astype(np.float32)
            new &= blob | ~table_coloured(lab, new | blob, floors, others=window > 0)
        window[new] = k + 1
        bx, by, bw, bh = cv2.boundingRect(new.view(np.uint8))
        boxes[k] = (bx + x0, by + y0, bw, bh)
        areas[k] = np.count_nonzero(new)
    return boxes, areas


def table_coloured(lab: np.ndarray, grown: np.ndarray, floors: np.ndarray, *,
                   others: np.ndarray | None = None) -> np.ndarray:
    """(H, W) bool: the pixels whose LAB colour lies within ``floors`` (per channel) of the
    median of a 3 px band around ``grown`` (less ``others``): the table's colour there;
    nothing where the band is empty."""
    ring = cv2.dilate(grown.view(np.uint8), np.ones((7, 7), np.uint8)).view(bool) & ~grown
    if others is not None:
        ring &= ~others
    if not ring.any():
        return np.zeros(grown.shape, bool)
    table = np.median(lab[ring], axis=0)
    near: np.ndarray = (np.abs(lab - table) <= floors).all(axis=2)
    return near


def _filled(mask: np.ndarray) -> np.ndarray:
    """``mask`` with the holes its outer contour encloses filled: the depth of a part a few
    pixels across drops single pixels inside it (edges, specular spots), and a part's
    region is whole."""
    contours, _ = cv2.findContours(mask.view(np.uint8), cv2.RETR_EXTERNAL,
                                   cv2.CHAIN_APPROX_NONE)
    out = np.zeros(mask.shape, np.uint8)
    cv2.drawContours(out, contours, -1, 1, thickness=cv2.FILLED)
    return out.view(bool)


__all__ = ['small_blobs_from_depth', 'table_coloured']
