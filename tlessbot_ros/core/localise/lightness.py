"""Parts alike in chroma but not in lightness: a white part against a black one.

The colour split (:func:`~tlessbot_ros.core.localise.blob_split.colour_pieces`) reads chroma
only (a / L, b / L), which shading leaves alone; it cannot tell a white block from a black
bracket touching it. :func:`lightness_pieces` divides such a blob where the two lightnesses lie
further apart than a part's own shading takes them, and :func:`two_lightnesses` is the top
view's check used by the fusion: a grey part's face that is dark from the side is lit from the
top, a black part is black from both. Lightness is OpenCV's 8-bit CIE-LAB L (0-255).
"""
from __future__ import annotations

from collections.abc import Callable
from functools import partial

import cv2
import numpy as np

from tlessbot_ros.core.localise.blob_split import fill_from_nearest, two_means
from tlessbot_ros.core.localise.cues import opened
from tlessbot_ros.core.localise.params import SegmentationParams
from tlessbot_ros.core.localise.part_scale import whole_part_px


def lightness_pieces(blob: np.ndarray, rgb: np.ndarray, params: SegmentationParams
                     ) -> list[np.ndarray]:
    """Divide a blob of two parts alike in chroma but not in lightness (a white block against
    a black bracket), which :func:`~tlessbot_ros.core.localise.blob_split.colour_pieces`
    cannot tell apart: 2-means on CIE-LAB L, kept when the clusters' median L differ by more than
    ``lightness_split_ratio`` (shading divides the light a face reflects by a few at most)
    and each piece is as large as the smallest whole part of the set
    (:func:`.part_scale.whole_part_px`; the parts must be known: a piece of a part partly
    hidden is smaller than the part). ``[blob]`` otherwise. Bool masks of the blob's crop."""
    if params.lightness_split_ratio <= 0 or not params.whole_parts:
        return [blob]
    lightness = cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab)[..., 0][blob].astype(np.float32)
    min_piece = max(params.min_area_px, int(params.colour_split_min_share * len(lightness)))
    if len(lightness) < 2 * min_piece:
        return [blob]
    cut = _lightness_cut(lightness)
    dark, light = lightness[lightness < cut], lightness[lightness >= cut]
    if min(dark.size, light.size) < min_piece or \
            lightness_ratio(lightness, cut) <= params.lightness_split_ratio:
        return [blob]
    cluster = np.zeros(blob.shape, np.int32)
    cluster[blob] = np.where(lightness >= cut, 2, 1)
    seeds = np.zeros(blob.shape, np.int32)
    n_seeds = 0
    for c in (1, 2):
        m = opened((cluster == c), 1).view(np.uint8)
        n, comp, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        largest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) if n > 1 else 0
        if largest and stats[largest, cv2.CC_STAT_AREA] >= min_piece:
            n_seeds += 1
            seeds[comp == largest] = n_seeds
    if n_seeds < 2:
        return [blob]
    owner = fill_from_nearest(seeds, blob & (seeds == 0))
    pieces = [owner == k for k in (1, 2)]
    smallest_part_px = whole_part_px(params.whole_parts)
    if min(cv2.countNonZero(p.view(np.uint8)) for p in pieces) < smallest_part_px:
        return [blob]
    return pieces


# The darkest lightness (OpenCV's 8-bit L) a ratio is taken against: below it, the noise.
_DARKEST_L = 10.0


def _lightness_cut(lightness: np.ndarray) -> float:
    """The boundary of the 2-means clusters of (N,) float32 lightness values (at most ~800
    of them clustered)."""
    sample = np.ascontiguousarray(lightness[::max(1, len(lightness) // 800)].reshape(-1, 1))
    return float(two_means(sample).mean())


def lightness_ratio(lightness: np.ndarray, cut: float | None = None, *,
                    min_share: float = 0.0) -> float:
    """The brighter 2-means cluster's median over the darker's (taken as at least 10) of
    (N,) float32 8-bit CIE-LAB L values; 1 with fewer than two values, or where a cluster
    holds less than ``min_share`` of them (none: one cluster)."""
    if lightness.size < 2:
        return 1.0
    cut = _lightness_cut(lightness) if cut is None else cut
    dark, light = lightness[lightness < cut], lightness[lightness >= cut]
    if min(dark.size, light.size) <= min_share * lightness.size:
        return 1.0
    return float(np.median(light)) / max(float(np.median(dark)), _DARKEST_L)


def top_check(top_rgb: np.ndarray | None, top_labels: np.ndarray, owners: list[int],
              ratio: float) -> Callable[[], bool] | None:
    """The top view's check of a side blob's lightness halves (:func:`two_lightnesses` at
    ``ratio``, asked only where there are halves), None without the top image or with the
    check off (``ratio`` 0)."""
    if top_rgb is None or ratio <= 0:
        return None
    return partial(two_lightnesses, top_rgb, top_labels, owners, ratio)


def two_lightnesses(top_rgb: np.ndarray, top_labels: np.ndarray, owners: list[int],
                     ratio: float) -> bool:
    """Whether the top view's pixels of the blobs ``owners`` hold two lightness clusters
    (2-means on CIE-LAB L) whose medians differ by more than ``ratio``: a black part against
    a white one, which the top sees as such, where a grey part's shaded face (dark from the
    side only) is lit from the top."""
    mine = np.isin(top_labels, owners)
    if not mine.any():
        return True
    rows, cols = np.nonzero(mine)
    window = np.s_[rows.min():rows.max() + 1, cols.min():cols.max() + 1]
    lightness = cv2.cvtColor(np.ascontiguousarray(top_rgb[window]), cv2.COLOR_RGB2Lab)[..., 0]
    return lightness_ratio(lightness[mine[window]].astype(np.float32),
                           min_share=TOP_MIN_SHARE) > ratio


# The smaller lightness of a top blob is a part's only from this share of its pixels on (a
# part's front face seen at an angle, a shadow's rim, are less), as the colour split's pieces.
TOP_MIN_SHARE = 0.12
