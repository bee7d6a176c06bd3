"""Crop normalisation and HOG descriptors for recognising textureless parts (paper §3.2).

A region of interest (box, optionally a mask) is cut out square, resized to ``crop_px`` (60 by
default) and its intensities are normalised so that the PLA colour and the lighting matter
little: with a mask the object is contrast-stretched into ``[object_floor, 1]`` and the
background is set to 0, so the silhouette and the shading edges carry the class. The HOG is
Dalal and Triggs' [1] with unsigned gradients, ``cell_px`` cells, ``bins`` orientation bins and
L2-Hys normalisation over blocks of 2×2 cells with a one-cell stride; the paper's choice is cells
of 6×6 px and 4 bins (§3.2, Fig. 10). OpenCV's ``cv2.HOGDescriptor`` is used because it takes a
fraction of ``skimage.feature.hog``'s time per crop (docs/bench/code-figures.md); the two are
not numerically identical, so train and test with this module only.

References:
    [1] N. Dalal and B. Triggs, "Histograms of oriented gradients for human detection",
        CVPR 2005.
    [2] Sensors 2020, 20, 2203 (the seed paper), §3.2 and §6.1.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from functools import lru_cache

import cv2
import numpy as np

from tlessbot_ros.core.common import mask_box

CROP_MODES = ('mask', 'box')
BOX_SIZE_DIM = 2


@dataclass(frozen=True)
class HogParams:
    """Crop normalisation and HOG settings (stored in the classifier model file).

    Attributes:
        crop_px: side of the square normalised crop in pixels; must be a multiple of
            ``cell_px`` and at least two cells.
        cell_px: HOG cell side in pixels (paper: 6).
        bins: orientation bins over 0–180° (paper: 4).
        block_cells: block side in cells; blocks step by one cell (Dalal–Triggs: 2).
        margin_frac: margin added around the box on each side, as a fraction of its longer side.
        object_floor: with a mask, the darkest object pixel maps to this grey level (0–1) and
            the background to 0, so the silhouette always has contrast.
        low_percentile, high_percentile: the intensity percentiles stretched to the output range.
        crop_mode: ``'mask'`` (the paper's way): with a mask, the background is blanked out
            and the silhouette carries the class; ``'box'``: regions are cut by their box
            alone, background and neighbours included, the same whether the localiser gives
            a silhouette or only a box (models trained on cluttered crops,
            :mod:`tlessbot_ros.sim.clutter`).
        box_size: append the box's angular size to the HOG: ``log(longer side / fx)`` and
            ``log(shorter side / fx)`` (2 values; the 60×60 crop throws the size away, and
            parts of a set often differ most in it). Needs the frame's focal length.
        focal_px: focal length used for ``box_size`` where a frame's is not given (the
            training camera's).
    """

    crop_px: int = 60
    cell_px: int = 6
    bins: int = 4
    block_cells: int = 2
    margin_frac: float = 0.06
    object_floor: float = 0.3
    low_percentile: float = 2.0
    high_percentile: float = 98.0
    crop_mode: str = 'mask'
    box_size: bool = False
    focal_px: float = 615.0

    def __post_init__(self) -> None:
        if not self.focal_px > 0:
            raise ValueError(f'focal_px must be > 0, got {self.focal_px}')
        if self.crop_mode not in CROP_MODES:
            raise ValueError(f'crop_mode must be one of {CROP_MODES}, got {self.crop_mode!r}')
        if self.cell_px < 2:
            raise ValueError(f'cell_px must be >= 2, got {self.cell_px}')
        if self.crop_px % self.cell_px:
            raise ValueError(f'crop_px ({self.crop_px}) must be a multiple of cell_px '
                             f'({self.cell_px}); use a cell size that divides it, e.g. 2, 3, '
                             '4, 5, 6, 10, 12, 15 or 20 for 60 px crops')
        if self.crop_px // self.cell_px < self.block_cells:
            raise ValueError(f'crop_px ({self.crop_px}) must hold at least one block of '
                             f'{self.block_cells}x{self.block_cells} cells of {self.cell_px} px')
        if not 2 <= self.bins <= 64:
            raise ValueError(f'bins must be in [2, 64], got {self.bins}')
        if self.block_cells < 1:
            raise ValueError(f'block_cells must be >= 1, got {self.block_cells}')
        if not 0.0 <= self.object_floor < 1.0:
            raise ValueError(f'object_floor must be in [0, 1), got {self.object_floor}')
        if not 0.0 <= self.low_percentile < self.high_percentile <= 100.0:
            raise ValueError('need 0 <= low_percentile < high_percentile <= 100')
        if self.margin_frac < 0.0:
            raise ValueError(f'margin_frac must be >= 0, got {self.margin_frac}')

    @property
    def hog_dim(self) -> int:
        """Length of the HOG: blocks × cells per block × bins."""
        blocks = self.crop_px // self.cell_px - self.block_cells + 1
        return blocks * blocks * self.block_cells ** 2 * self.bins

    @property
    def feature_dim(self) -> int:
        """Length of one descriptor: the HOG, plus 2 with ``box_size``."""
        return self.hog_dim + (BOX_SIZE_DIM if self.box_size else 0)

    def to_dict(self) -> dict[str, float | int | str]:
        return asdict(self)


@lru_cache(maxsize=16)
def _descriptor(params: HogParams) -> cv2.HOGDescriptor:
    cell, block = params.cell_px, params.cell_px * params.block_cells
    return cv2.HOGDescriptor((params.crop_px, params.crop_px), (block, block), (cell, cell),
                             (cell, cell), params.bins)


def _to_gray(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.ndim == 3 and image.shape[2] in (3, 4):
        image = image[..., :3]
        if image.dtype != np.uint8:
            image = image.astype(np.float32)
        return cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
    if image.ndim == 2:
        return image.astype(np.float32, copy=False)  # no per-crop copy of a grey frame
    raise ValueError(f'image must be (H, W) grey or (H, W, 3|4) RGB(A), got shape {image.shape}')


def box_from_mask(mask: np.ndarray) -> tuple[int, int, int, int]:
    box = mask_box(mask)
    if box[2] == 0:
        raise ValueError('mask is empty: nothing to crop')
    return box


def _square_window(box: Sequence[float], margin_frac: float) -> tuple[int, int, int]:
    x, y, w, h = (float(v) for v in box)
    if w <= 0 or h <= 0:
        raise ValueError(f'box must have positive width and height, got {tuple(box)}')
    side = max(w, h) * (1.0 + 2.0 * margin_frac)
    side_i = max(int(round(side)), 2)
    x0 = int(round(x + w / 2.0 - side_i / 2.0))
    y0 = int(round(y + h / 2.0 - side_i / 2.0))
    return x0, y0, side_i


def _cut(image: np.ndarray, x0: int, y0: int, side: int, fill: float) -> np.ndarray:
    """``image[y0:y0+side, x0:x0+side]``, padded with ``fill`` where it leaves the image."""
    height, width = image.shape[:2]
    out = np.full((side, side), fill, dtype=image.dtype)  # fill may be NaN or False
    xa, ya = max(x0, 0), max(y0, 0)
    xb, yb = min(x0 + side, width), min(y0 + side, height)
    if xb > xa and yb > ya:
        out[ya - y0:yb - y0, xa - x0:xb - x0] = image[ya:yb, xa:xb]
    return out


def normalise_crop(image: np.ndarray, box: Sequence[float] | None = None,
                   mask: np.ndarray | None = None, *,
                   params: HogParams = HogParams()) -> np.ndarray:
    """Cut one region out of an image and normalise it for HOG.

    Args:
        image: (H, W, 3) RGB (uint8 or float) or (H, W) grey image of the whole frame.
        box: (x, y, width, height) of the region in pixels (BOP ``bbox`` convention); by default
            the box of ``mask``, or the whole image.
        mask: optional (H, W) bool mask of the object's visible pixels. Pixels outside it become
            background (0) and only pixels inside set the intensity stretch.
        params: crop size and intensity settings.

    Returns:
        (crop_px, crop_px) uint8 normalised crop. The region is padded to a square around the
        box centre (padding outside the frame is background) before resizing, so the aspect
        ratio of the part is kept.
    """
    gray = _to_gray(image)
    if mask is not None:
        mask = np.asarray(mask)
        if mask.shape != gray.shape:
            raise ValueError(f'mask shape {mask.shape} differs from image shape {gray.shape}')
    if box is None:
        box = box_from_mask(mask) if mask is not None else (0, 0, gray.shape[1], gray.shape[0])
    x0, y0, side = _square_window(box, params.margin_frac)
    n = params.crop_px
    if mask is None:
        region = _cut(gray, x0, y0, side, np.nan)
        outside = np.isnan(region)
        if outside.all():
            raise ValueError(f'box {tuple(box)} lies outside the image')
        region[outside] = region[~outside].mean()
        region = _resize(region, n)
        lo, hi = _low_high(region.ravel(), params)
        scaled = (region - lo) / max(hi - lo, 1e-6)
        return (np.clip(scaled, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    # Cut before converting: the full-frame mask is never copied.
    region_mask = _cut(mask, x0, y0, side, False).astype(np.float32)
    region = _cut(gray, x0, y0, side, 0.0)
    # Normalised convolution: resample object pixels only, so the background never leaks in.
    weight = _resize(region_mask, n)
    region = _resize(region * region_mask, n)
    region /= np.maximum(weight, 1e-3)
    inside = weight > 0.5
    if not inside.any():
        raise ValueError('mask has no pixels inside the box')
    lo, hi = _low_high(region[inside], params)
    # Soft mask edge: a resized mask is fractional on the silhouette, which keeps it anti-aliased.
    floor = params.object_floor
    scaled = np.clip((region - lo) * ((1.0 - floor) / max(hi - lo, 1e-6)), 0.0, 1.0 - floor)
    scaled += floor
    scaled *= weight
    scaled[weight <= 1e-3] = 0.0
    return (np.clip(scaled, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _resize(square: np.ndarray, n: int) -> np.ndarray:
    """(side, side) float32 -> (n, n): bilinear up to k·n, then an integer k×k box average.

    Close to ``INTER_AREA`` (anti-aliased) at a third of its cost: OpenCV's area resampling
    is fast only for integer factors.
    """
    side = square.shape[0]
    if side <= n:
        return cv2.resize(square, (n, n), interpolation=cv2.INTER_LINEAR)
    k = max(side // n, 2)
    if side != k * n:
        square = cv2.resize(square, (k * n, k * n), interpolation=cv2.INTER_LINEAR)
    return cv2.resize(square, (n, n), interpolation=cv2.INTER_AREA)


def _low_high(values: np.ndarray, params: HogParams) -> tuple[float, float]:
    """The (low, high) intensity percentiles of ``values`` (one partition, linear rule)."""
    position = np.array([params.low_percentile, params.high_percentile]) / 100.0 * (
        len(values) - 1)
    low = np.floor(position).astype(np.int64)
    high = np.minimum(low + 1, len(values) - 1)
    part = np.partition(values, np.unique(np.concatenate([low, high])))
    frac = position - low
    lo, hi = part[low] * (1.0 - frac) + part[high] * frac
    return float(lo), float(hi)


def hog_features(crops: np.ndarray | Sequence[np.ndarray], *,
                 params: HogParams = HogParams()) -> np.ndarray:
    """HOG descriptors of normalised crops.

    Args:
        crops: (N, crop_px, crop_px) uint8 crops from :func:`normalise_crop`, or one crop.
        params: HOG settings; must match the ones the crops were made with.

    Returns:
        (N, params.hog_dim) float32 descriptors (L2-Hys normalised blocks, OpenCV order);
        without the box size, which only :func:`describe_regions` appends.
    """
    crops = np.asarray(crops)
    if crops.ndim == 2:
        crops = crops[None]
    n = params.crop_px
    if crops.ndim != 3 or crops.shape[1:] != (n, n):
        raise ValueError(f'crops must be (N, {n}, {n}), got shape {crops.shape}')
    if crops.dtype != np.uint8:
        raise ValueError(f'crops must be uint8 (from normalise_crop), got {crops.dtype}')
    descriptor = _descriptor(params)
    out = np.empty((len(crops), params.hog_dim), np.float32)
    for i, crop in enumerate(crops):
        out[i] = np.ravel(descriptor.compute(np.ascontiguousarray(crop)))
    return out


def box_size_features(boxes: Sequence[Sequence[float]], focal_px: float) -> np.ndarray:
    """(N, 2) float32 ``log(longer side / focal_px)``, ``log(shorter side / focal_px)`` of N
    (x, y, w, h) pixel boxes: their angular size (sides of at least one pixel)."""
    if not focal_px > 0:
        raise ValueError(f'focal_px must be > 0, got {focal_px}')
    sides = np.maximum(np.asarray(boxes, np.float64).reshape(-1, 4)[:, 2:], 1.0)
    return np.log(np.stack([sides.max(axis=1), sides.min(axis=1)], axis=1)
                  / focal_px).astype(np.float32)


def describe_regions(image: np.ndarray, boxes: Sequence[Sequence[float]] | None = None,
                     masks: Sequence[np.ndarray] | None = None, *,
                     params: HogParams = HogParams(),
                     focal_px: float | None = None) -> np.ndarray:
    """Normalise and describe all regions of one frame (batched).

    Args:
        image: (H, W, 3) RGB or (H, W) grey frame.
        boxes: N boxes (x, y, width, height) in pixels, or None to use the masks' boxes.
        masks: N (H, W) bool masks, or None.
        focal_px: the frame's focal length (for ``params.box_size``; default
            ``params.focal_px``).

    Returns:
        (N, params.feature_dim) float32 descriptors, in the order of the regions.
    """
    if boxes is None and masks is None:
        raise ValueError('give boxes, masks or both')
    count = len(boxes) if boxes is not None else len(masks)  # type: ignore[arg-type]
    if boxes is not None and masks is not None and len(masks) != count:
        raise ValueError(f'{count} boxes but {len(masks)} masks')
    if masks is not None and boxes is None and (params.crop_mode == 'box' or params.box_size):
        boxes = [box_from_mask(mask) for mask in masks]
    if params.crop_mode == 'box':  # cut by the box, background kept
        masks = None
    gray = _to_gray(image)
    crops = np.empty((count, params.crop_px, params.crop_px), np.uint8)
    for i in range(count):
        crops[i] = normalise_crop(gray, None if boxes is None else boxes[i],
                                  None if masks is None else masks[i], params=params)
    hog = hog_features(crops, params=params)
    if not params.box_size:
        return hog
    assert boxes is not None   # from the masks above when params.box_size
    size = box_size_features(boxes, params.focal_px if focal_px is None else focal_px)
    return np.hstack([hog, size])
