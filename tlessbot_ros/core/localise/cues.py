"""The per-cue object masks of the segmentation (paper §3.1; the depth cue is ours).

Every cue gives two (h, w) bool masks at the cue scale: *candidates* (pixels that may belong
to a part) and *sure* object markers.

* **Histogram cut-offs.** Each cue channel (grey level, the three HED stains, the CIE-LAB
  chroma axes a and b), less a robust quadratic trend (uneven lighting), gets a cut-off read
  from its histogram: the background is the dominant peak; pixels further than
  ``cutoff_sigma`` robust standard deviations (and at least the channel's ``*_floor``) from it
  are object candidates, pixels beyond ``sure_sigma`` are sure
  object markers. With an empty-table image the same cut-offs are read on the difference to
  it, which makes patterned tables as easy as plain ones (the paper's "first guess").
* **Background subtraction** against an empty-table image: colour distance in LAB with a
  shadow test (a cast shadow darkens the table but keeps its chromaticity).
* **Depth** (not in the paper): height above the table plane; pixels with valid depth on the
  plane are table, which vetoes colour candidates there (shadows, dark table squares).
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, cast

import cv2
import numpy as np

from tlessbot_ros.core.localise.colour import (
    check_rgb,
    histogram_background_peak,
    remove_trend,
    rgb_to_hed,
    rgb_to_lab,
)
from tlessbot_ros.core.localise.params import SegmentationParams

if TYPE_CHECKING:
    from tlessbot_ros.core.common import CameraIntrinsics


# --------------------------------------------------------------------------- empty table
@dataclass(frozen=True)
class BackgroundModel:
    """An empty-table image prepared once for :func:`~tlessbot_ros.core.localise.segment`
    (colour spaces at cue scale).

    Attributes:
        rgb: (H, W, 3) uint8 full-resolution empty-table image.
        lab, hed: (h, w, 3) float32 LAB and HED images at ``scale``.
        scale: the cue scale they were computed at.
    """

    rgb: np.ndarray
    lab: np.ndarray
    hed: np.ndarray
    scale: float


def prepare_background(background: np.ndarray, *,
                       params: SegmentationParams = SegmentationParams()) -> BackgroundModel:
    """Convert an (H, W, 3) uint8 RGB empty-table image once, for repeated
    :func:`~tlessbot_ros.core.localise.segment`."""
    background = check_rgb(background, 'background')
    small = downscale(background, params.cue_scale)
    return BackgroundModel(rgb=background, lab=rgb_to_lab(small),
                           hed=rgb_to_hed(small, dark_level=params.hed_dark_level),
                           scale=params.cue_scale)


def downscale(rgb: np.ndarray, scale: float) -> np.ndarray:
    if scale == 1.0:
        return rgb
    return cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


# --------------------------------------------------------------------------- histogram cut-offs
def _cutoff_masks(channel: np.ndarray, floor: float, params: SegmentationParams,
                  *, peak: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(candidate, sure) masks of pixels far from the background peak on either side."""
    found_peak, sigma = histogram_background_peak(channel,
                                                  border_fraction=params.border_fraction)
    peak = found_peak if peak is None else peak
    dev = np.abs(channel - np.float32(peak))
    candidate = dev > max(params.cutoff_sigma * sigma, floor)
    sure = dev > max(params.sure_sigma * sigma, 2.0 * floor)
    return candidate, sure



def _channel_cutoffs(image: np.ndarray, channels: Iterable[int], floor: float,
                     params: SegmentationParams, reference: np.ndarray | None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Union of the (candidate, sure) cut-off masks of some channels of an (H, W, C) image.

    Without ``reference`` each channel loses its trend and the background peak is read from
    its histogram; with it (the empty table's image in the same space) the cut-offs apply to
    the difference, whose background peak is 0.
    """
    cand = np.zeros(image.shape[:2], bool)
    sure = np.zeros(image.shape[:2], bool)
    peak = None if reference is None else 0.0
    for c in channels:
        channel = remove_trend(image[..., c]) if reference is None else \
            image[..., c] - reference[..., c]
        a, b = _cutoff_masks(channel, floor, params, peak=peak)
        cand |= a
        sure |= b
    return cand, sure


def hed_masks(hed: np.ndarray, params: SegmentationParams,
              *, reference: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Union of the H, E and D histogram cut-offs: (candidate, sure) (H, W) bool masks.

    With ``reference`` (the empty table's HED image) the cut-offs apply to the difference.
    """
    return _channel_cutoffs(hed, range(3), params.hed_floor, params, reference)


def lab_masks(lab: np.ndarray, params: SegmentationParams,
              *, reference: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Chroma (a, b) histogram cut-offs: (candidate, sure) (H, W) bool masks."""
    return _channel_cutoffs(lab, (1, 2), params.lab_floor, params, reference)


def _grey_cue(small: np.ndarray, lab: np.ndarray, bgm: BackgroundModel | None,
              params: SegmentationParams) -> tuple[np.ndarray, np.ndarray]:
    return _channel_cutoffs(lab, (0,), params.grey_floor, params,
                            None if bgm is None else bgm.lab)


def _hed_cue(small: np.ndarray, lab: np.ndarray, bgm: BackgroundModel | None,
             params: SegmentationParams) -> tuple[np.ndarray, np.ndarray]:
    hed = rgb_to_hed(small, dark_level=params.hed_dark_level)
    return hed_masks(hed, params, reference=None if bgm is None else bgm.hed)


def _lab_cue(small: np.ndarray, lab: np.ndarray, bgm: BackgroundModel | None,
             params: SegmentationParams) -> tuple[np.ndarray, np.ndarray]:
    return lab_masks(lab, params, reference=None if bgm is None else bgm.lab)


# The colour cues of SegmentationParams.methods in the order segment() adds them, each
# (RGB and LAB at cue scale, empty table or None, params) -> (candidate, sure) masks.
# 'watershed' contributes the grey level (LAB's L) extremes.
COLOUR_CUES = (('watershed', _grey_cue), ('hed', _hed_cue), ('lab', _lab_cue))


# --------------------------------------------------------------------------- depth
_HEIGHT_COEF: dict[tuple[bytes, bytes, int, int, int, int], np.ndarray] = {}


def height_above_table(depth_m: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray, *,
                       scale: float = 1.0) -> np.ndarray:
    """Height of every depth pixel's 3D point above the table plane (world z = 0).

    A pixel (u, v) with z-depth d back-projects to ``d K^-1 (u, v, 1)`` in the optical frame;
    its world height is ``d (r3 . K^-1 (u, v, 1)) + t_z`` with r3 the third row of the
    camera's rotation, so one multiply-add per pixel with a cached coefficient image (lens
    distortion is ignored: the D415 colour stream is nearly distortion-free).

    Args:
        depth_m: (H, W) float z-depth in metres aligned to the colour image; 0 or NaN =
            invalid.
        K: (3, 3) intrinsic matrix of that image.
        T_world_camera: (4, 4) optical frame -> world (world z = 0 is the table, z up).
        scale: output scale; pixel (r, c) of the output samples the input at
            (floor(r / scale), floor(c / scale)) (the same pixels as ``cv2.INTER_NEAREST``).

    Returns:
        (round(H * scale), round(W * scale)) float32 heights in metres, NaN where invalid.
    """
    depth_m = np.asarray(depth_m)
    if depth_m.ndim != 2:
        raise ValueError(f'depth_m must be an (H, W) image, got shape {depth_m.shape}')
    K = np.asarray(K, dtype=np.float64)
    T = np.asarray(T_world_camera, dtype=np.float64)
    if K.shape != (3, 3) or T.shape != (4, 4):
        raise ValueError(f'K must be (3, 3) and T_world_camera (4, 4), got {K.shape} and '
                         f'{T.shape}')
    h, w = depth_m.shape
    hs, ws = int(round(h * scale)), int(round(w * scale))
    rows = np.minimum((np.arange(hs) / scale).astype(np.int64), h - 1)
    cols = np.minimum((np.arange(ws) / scale).astype(np.int64), w - 1)
    key = (K.tobytes(), T[2, :3].tobytes(), h, w, hs, ws)
    coef = _HEIGHT_COEF.get(key)
    if coef is None:
        r3 = T[2, :3]
        cu = (cols - K[0, 2]) / K[0, 0]
        cv = (rows - K[1, 2]) / K[1, 1]
        coef = (r3[0] * cu[None, :] + r3[1] * cv[:, None] + r3[2]).astype(np.float32)
        if len(_HEIGHT_COEF) > 16:
            _HEIGHT_COEF.clear()
        _HEIGHT_COEF[key] = coef
    step = 1.0 / scale
    if (hs, ws) == (h, w):
        d = depth_m
    elif step == int(step) and rows[-1] == (hs - 1) * int(step):
        d = depth_m[::int(step), ::int(step)][:hs, :ws]  # same pixels, cheaper than a gather
    else:
        d = depth_m[rows[:, None], cols[None, :]]
    d = d.astype(np.float32)
    d[~(d > 0)] = np.nan  # 0 and NaN invalid (NaN > 0 is False)
    d *= coef
    d += np.float32(T[2, 3])
    return d


@dataclass
class DepthCue:
    candidate: np.ndarray  # object candidates (cue scale)
    sure: np.ndarray  # sure object
    table: np.ndarray  # valid depth on the table plane
    sigma_m: float  # robust height noise of the table
    surfaces: Surfaces | None = None  # for the depth split (None: no depth image given)
    height_m: np.ndarray | None = None  # (h, w) height above the table, NaN invalid
    thin_regions: np.ndarray | None = None  # (h, w) int32 thin parts' lifted colour regions


@dataclass
class Surfaces:
    """What depth says about the surfaces of a view, at the cue scale, for the depth split
    of touching parts (``SegmentationParams.depth_split_jump``)."""

    solid: np.ndarray  # (h, w) bool: valid, above the candidate height, off range jumps
    table: np.ndarray  # (h, w) bool: valid, below the table height (unfiltered)
    depth_m: np.ndarray  # (h, w) float32 depth, 0 = invalid


def view_depth_cue(depth_m: np.ndarray, intrinsics: CameraIntrinsics | np.ndarray,
                   T_world_camera: np.ndarray,
                    shape: tuple[int, ...], cue_shape: tuple[int, ...],
                    params: SegmentationParams, *, with_surfaces: bool = True) -> DepthCue:
    """The depth cue at the cue scale of a view: ``shape`` is the colour image's, ``cue_shape``
    the downscaled one's; ``intrinsics`` a CameraIntrinsics or a (3, 3) K; with its surfaces
    (for the depth split) if ``with_surfaces`` and ``params.depth_split_jump`` > 0."""
    K = np.asarray(getattr(intrinsics, 'K', intrinsics))
    height = height_above_table(depth_m, K, T_world_camera, scale=cue_shape[0] / shape[0])
    size = (cue_shape[1], cue_shape[0])
    if height.shape != cue_shape[:2]:
        height = cv2.resize(height, size, interpolation=cv2.INTER_NEAREST)
    depth: np.ndarray | None = None
    if with_surfaces and params.depth_split_jump > 0:
        # the same pixels as the height map (nearest neighbour), holes as 0
        depth = np.nan_to_num(np.asarray(depth_m, np.float32), nan=0.0, posinf=0.0)
        if depth.shape != cue_shape[:2]:
            depth = cv2.resize(depth, size, interpolation=cv2.INTER_NEAREST)
    return depth_cue(height, params, depth=depth)


def range_jumps(depth_m: np.ndarray, ratio: float) -> np.ndarray:
    """Pixels on a range discontinuity: a 4-neighbour's depth differs by more than ``ratio``
    times the nearer depth (both valid).

    An occluding contour or the seam between two parts shows as such a jump; one surface
    does only where it is seen at a grazing angle (with ratio r and focal length f pixels,
    steeper than atan(r f) to the line of sight: 81 deg for r = 0.02 at f = 307).

    Args:
        depth_m: (H, W) float depth in metres, 0 (or negative) = invalid.
        ratio: the relative jump, e.g. 0.02.

    Returns:
        (H, W) bool, both pixels of every jumping pair.
    """
    d = np.asarray(depth_m, np.float32)
    valid = d > 0
    out = np.zeros(d.shape, bool)
    for a, b in ((d[:, 1:], d[:, :-1]), (d[1:], d[:-1])):
        jump = np.abs(a - b) > np.float32(ratio) * np.minimum(a, b)
        jump &= (a > 0) & (b > 0)
        if a.shape[1] < d.shape[1]:
            out[:, 1:] |= jump
            out[:, :-1] |= jump
        else:
            out[1:] |= jump
            out[:-1] |= jump
    return out & valid

def table_height_m(params: SegmentationParams, sigma_m: float) -> float:
    """The height (m) below which a valid depth pixel is table: ``depth_table_height_m``,
    raised to half ``depth_noise_k`` robust deviations ``sigma_m`` of the table's height."""
    return max(params.depth_table_height_m, 0.5 * params.depth_noise_k * sigma_m)


def depth_cue(height: np.ndarray, params: SegmentationParams, *,
               depth: np.ndarray | None = None) -> DepthCue:
    """Object / table masks from a (h, w) height map (NaN invalid); with the (h, w) depth of
    the same pixels (metres, 0 invalid) also its surfaces (``depth_split_jump``)."""
    valid = ~np.isnan(height)
    filled = height.copy()
    filled[~valid] = 0.0
    sample = filled[::2, ::2][valid[::2, ::2]]
    sample = sample[np.abs(sample) < 0.02]
    sigma = 1.4826 * float(np.median(np.abs(sample))) if sample.size > 50 else 0.0
    r = params.depth_filter_px
    filtered = cv2.medianBlur(filled, r) if r > 1 else filled
    k = params.depth_noise_k
    low = max(params.depth_min_height_m, k * sigma)
    high = max(params.depth_sure_height_m, 1.5 * k * sigma)
    table_h = table_height_m(params, sigma)
    high_raw = valid & (filled > low)
    # The median over a hole's neighbours fills it (invalid pixels count as table height,
    # so they never make an object on their own).
    candidate = filtered > low
    sure = filtered > high
    if r > 1 and params.depth_vote_valid:
        # ... but a dark part seen from afar returns depth in scattered pixels only (40-70 %
        # holes), which that median calls table. So a hole, or a high pixel, is also high
        # when most of the *valid* pixels of its window are (holes abstain); a valid pixel
        # at table height stays what it reads.
        votes = cv2.boxFilter(valid.view(np.uint8), cv2.CV_16U, (r, r), normalize=False)

        def majority(mask: np.ndarray) -> np.ndarray:
            more: np.ndarray = 2 * cv2.boxFilter(mask.view(np.uint8), cv2.CV_16U, (r, r),
                                                 normalize=False) > votes
            return more

        candidate |= majority(high_raw) & (~valid | high_raw)
        high_sure = valid & (filled > high)
        sure |= majority(high_sure) & (~valid | high_sure)
    table = valid & (filtered < table_h) & (filled < table_h)
    surfaces = None
    if depth is not None:
        solid = high_raw & ~range_jumps(depth, params.depth_split_jump)
        surfaces = Surfaces(solid, valid & (filled < table_h), np.asarray(depth, np.float32))
    return DepthCue(candidate, sure, table, sigma, surfaces, height)



# --------------------------------------------------------------------------- empty-table change
def background_change(lab: np.ndarray, bg_lab: np.ndarray, params: SegmentationParams, *,
                       shadow: np.ndarray | None = None) -> np.ndarray:
    """LAB distance to the empty table above ``background_delta_e``, shadows excluded."""
    diff = lab - bg_lab
    delta_e_sq = np.einsum('ijk,ijk->ij', diff, diff)
    if shadow is None:
        shadow = shadow_mask(lab, bg_lab, params)
    return cast(np.ndarray, (delta_e_sq > params.background_delta_e ** 2) & ~shadow)


def shadow_mask(lab: np.ndarray, bg_lab: np.ndarray, params: SegmentationParams) -> np.ndarray:
    """Pixels that look like the empty table darkened by a cast shadow.

    A shadow scales the table's colour: the luminance ratio lies in ``shadow_ratio`` and the
    chroma (a, b) shrinks roughly in proportion, so a / L and b / L stay close to the table's.
    """
    lo, hi = params.shadow_ratio
    L, bL = lab[..., 0] + 1.0, bg_lab[..., 0] + 1.0
    ratio = L / bL
    da = np.abs(lab[..., 1] - bg_lab[..., 1] * ratio)
    db = np.abs(lab[..., 2] - bg_lab[..., 2] * ratio)
    return (ratio > lo) & (ratio < hi) & (np.maximum(da, db) < params.shadow_chroma)


# --------------------------------------------------------------------------- morphology
def eroded(mask: np.ndarray, radius: int) -> np.ndarray:
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.erode(mask.view(np.uint8), kernel).astype(bool)


def opened(mask: np.ndarray, radius: int) -> np.ndarray:
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.morphologyEx(mask.view(np.uint8), cv2.MORPH_OPEN, kernel).astype(bool)
