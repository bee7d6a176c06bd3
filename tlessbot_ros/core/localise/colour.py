"""Colour spaces and histogram statistics of the segmentation cues (paper §3.1).

* **HED colour deconvolution** (Ruifrok & Johnston, Anal. Quant. Cytol. Histol. 23(4), 2001)
  through a 256-entry optical-density lookup table and one ``cv2.transform`` with the same
  stain matrix as ``skimage.color.rgb2hed``: dark parts stand out in H, light ones in E.
* **CIE-LAB** (``cv2.cvtColor`` on float RGB, true L in [0, 100]): translucent light-yellow
  parts stand out on the b (yellow) axis, pink on a.
* **Histogram background peak**: the table is the dominant peak of a channel's histogram; its
  robust spread sets the cut-offs of :mod:`~tlessbot_ros.core.localise.cues`.
* **Trend removal**: a robust quadratic surface (uneven lighting) is subtracted first.

All images are (H, W, 3) uint8 RGB.
"""
from __future__ import annotations

from typing import cast

import cv2
import numpy as np

from tlessbot_ros.core.localise.surface_fit import robust_quadratic_fit

# Stain OD vectors (rows: haematoxylin, eosin, DAB) of Ruifrok & Johnston (2001), as used by
# skimage.color.rgb2hed; the deconvolution matrix is their inverse.
_RGB_FROM_HED = np.array([[0.65, 0.70, 0.29], [0.07, 0.99, 0.11], [0.27, 0.57, 0.78]])
_HED_FROM_RGB = np.linalg.inv(_RGB_FROM_HED)


def _od_lut(dark_level: int) -> np.ndarray:
    """(1, 256, 3) float32 optical density log(max(I, 1e-6)) / log(1e-6) of skimage, with
    intensities below ``dark_level`` clamped to it (the log amplifies noise near black)."""
    v = np.maximum(np.arange(256), dark_level) / 255.0
    od = (np.log(np.maximum(v, 1e-6)) / np.log(1e-6)).astype(np.float32)
    return cast(np.ndarray, np.repeat(od.reshape(256, 1, 1), 3, axis=2).reshape(1, 256, 3).copy())


_OD_LUTS: dict[int, np.ndarray] = {}

_LAB8_TO_LAB = np.array([[100.0 / 255.0, 0, 0, 0], [0, 1, 0, -128], [0, 0, 1, -128]], np.float32)


def check_rgb(rgb: np.ndarray, name: str = 'rgb') -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f'{name} must be an (H, W, 3) RGB image, got shape {rgb.shape}')
    if rgb.dtype != np.uint8:
        raise ValueError(f'{name} must be uint8 (0-255), got {rgb.dtype}; convert with '
                         'np.clip(x * 255, 0, 255).astype(np.uint8) for float images')
    return np.ascontiguousarray(rgb)


def rgb_to_hed(rgb: np.ndarray, *, dark_level: int = 0) -> np.ndarray:
    """HED stain separation of an RGB image (colour deconvolution, Ruifrok & Johnston 2001).

    Args:
        rgb: (H, W, 3) uint8 RGB.
        dark_level: intensities below this are clamped to it before the logarithm (0 = the
            exact skimage transform).

    Returns:
        (H, W, 3) float32 stain densities (haematoxylin, eosin, DAB), the same values as
        ``skimage.color.rgb2hed`` before its clipping at 0 (negative values are kept: they
        carry the "lighter than the stain" side that light parts fall on).
    """
    rgb = check_rgb(rgb)
    if not 0 <= dark_level <= 255:
        raise ValueError(f'dark_level must be in [0, 255], got {dark_level}')
    lut = _OD_LUTS.get(dark_level)
    if lut is None:
        lut = _OD_LUTS.setdefault(dark_level, _od_lut(dark_level))
    od = cv2.LUT(rgb, lut)
    # cv2.transform computes m @ pixel; stains = od @ HED_FROM_RGB, so m is the transpose.
    return cv2.transform(od, _HED_FROM_RGB.T.astype(np.float32))


def rgb_to_lab(rgb: np.ndarray) -> np.ndarray:
    """CIE-LAB (D65) of an RGB image: (H, W, 3) float32, L in [0, 100], a and b signed.

    Computed by OpenCV's 8-bit conversion, which is cheaper than its float input, and
    rescaled, so values are quantised to 100/255 in L and 1 in a, b
    (docs/bench/code-figures.md).
    """
    rgb = check_rgb(rgb)
    lab8 = cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab)
    return cv2.transform(lab8.astype(np.float32), _LAB8_TO_LAB)


# --------------------------------------------------------------------------- histograms
def histogram_background_peak(channel: np.ndarray, *, bins: int = 512, sample_step: int = 2,
                              border_fraction: float = 0.0) -> tuple[float, float]:
    """Dominant histogram peak of a channel and its robust spread.

    The background covers most of a table image, so it is the highest histogram peak; its
    spread is the half width at half maximum of that peak divided by sqrt(2 ln 2) (the
    standard deviation of a Gaussian with that width), which ignores the objects' pixels.

    Args:
        channel: (H, W) float image.
        bins: histogram bins between the channel's minimum and maximum.
        sample_step: use every n-th row and column (speed; the histogram barely changes).
        border_fraction: if > 0, only a frame of this relative width along the image border
            is used (the table surrounds the parts in a table scene).

    Returns:
        (peak, sigma) in the channel's units; sigma > 0.
    """
    sample = np.asarray(channel, dtype=np.float32)[::sample_step, ::sample_step]
    if border_fraction > 0.0:
        h, w = sample.shape
        bh, bw = max(int(h * border_fraction), 1), max(int(w * border_fraction), 1)
        sample = np.concatenate([sample[:bh].ravel(), sample[-bh:].ravel(),
                                 sample[bh:-bh, :bw].ravel(), sample[bh:-bh, -bw:].ravel()])
        sample = sample.reshape(-1, 1)
    sample = np.ascontiguousarray(sample)
    lo, hi, _, _ = cv2.minMaxLoc(sample)
    if not hi > lo:
        return float(lo), 1e-6
    hist = cv2.calcHist([sample], [0], None, [bins], [float(lo), float(hi) + 1e-6]).ravel()
    hist = cv2.GaussianBlur(hist.reshape(-1, 1), (1, 7), 1.5).ravel()
    width = (hi - lo) / bins
    k = int(np.argmax(hist))
    half = hist[k] / 2.0
    left = k
    while left > 0 and hist[left] > half:
        left -= 1
    right = k
    while right < bins - 1 and hist[right] > half:
        right += 1
    hwhm = max(0.5 * (right - left), 0.5) * width
    return float(lo + (k + 0.5) * width), float(hwhm / np.sqrt(2.0 * np.log(2.0)))


_SAMPLE_GRIDS: dict[tuple[int, int], tuple[np.ndarray, np.ndarray]] = {}


def _sample_grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) float64 coordinates in [-0.5, 0.5] of an (h, w) sample grid, made once per shape
    (the trend of six channels per view is evaluated on the same grid every frame)."""
    grid = _SAMPLE_GRIDS.get(shape)
    if grid is None:
        gy, gx = np.mgrid[0:shape[0], 0:shape[1]]
        x = gx / max(shape[1] - 1, 1) - 0.5
        y = gy / max(shape[0] - 1, 1) - 0.5
        x.setflags(write=False)
        y.setflags(write=False)
        if len(_SAMPLE_GRIDS) > 16:
            _SAMPLE_GRIDS.clear()
        grid = _SAMPLE_GRIDS.setdefault(shape, (x, y))
    return grid


def remove_trend(channel: np.ndarray, *, step: int = 8, iterations: int = 3) -> np.ndarray:
    """Subtract a robust quadratic surface in (x, y) from a channel (uneven lighting).

    The surface is fitted by least squares to every ``step``-th pixel, refitted twice
    without the pixels beyond 2.5 standard deviations (the objects).

    Args:
        channel: (H, W) float32.

    Returns:
        (H, W) float32 channel minus the fitted surface.
    """
    h, w = channel.shape
    sample = np.ascontiguousarray(channel[step // 2::step, step // 2::step], np.float64)
    coef = robust_quadratic_fit(sample, iterations)
    x, y = _sample_grid(sample.shape)
    surface = (coef[0] + coef[1] * x + coef[2] * y + coef[3] * x * x + coef[4] * x * y
               + coef[5] * y * y).astype(np.float32)
    # The sample grid covers [step/2, ... ] pixel centres; resize spans the same range closely.
    surface = cv2.resize(surface, (w, h), interpolation=cv2.INTER_LINEAR)
    return cast(np.ndarray, channel - surface)

