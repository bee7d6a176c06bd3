"""Photometric and crop augmentation of rendered training images, for CAD-only training that
holds on real cameras.

Renders differ from real colour frames in exposure, white balance, tone curve, sharpness,
sensor noise and compression; and the localiser cuts real parts with loose boxes that hold
background and pieces of neighbours. :func:`photometric` draws one random camera response
(the AAE and GDRNPP recipes of ``docs/sim-to-real-notes.md`` §1-2, as plain array operations)
and :func:`loose_box` one random localiser box. Every function takes a
``numpy.random.Generator`` and is deterministic given it.

References:
    [1] M. Sundermeyer et al., "Implicit 3D Orientation Learning for 6D Object Detection from
        RGB Images" (augmented autoencoder), ECCV 2018.
    [2] J. Tobin et al., "Domain Randomization for Transferring Deep Neural Networks from
        Simulation to the Real World", IROS 2017.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import cast

import cv2
import numpy as np


@dataclass(frozen=True)
class PhotometricParams:
    """Ranges of the random camera response (each drawn uniformly per image).

    Attributes:
        exposure: (min, max) gain on linear intensity.
        white_balance: largest relative change of the red and blue gains.
        gamma: (min, max) exponent of the tone curve applied to [0, 1] intensities.
        contrast: (min, max) factor about the image mean.
        blur_sigma_px: (min, max) Gaussian blur; drawn with probability ``blur_prob``.
        blur_prob: chance of a blur.
        noise_sigma: (min, max) Gaussian sensor noise in grey levels (of 255).
        jpeg_quality: (min, max) JPEG quality; compressed with probability ``jpeg_prob``.
        jpeg_prob: chance of a JPEG round trip.
        grey_prob: chance of a desaturated image.
    """

    exposure: tuple[float, float] = (0.5, 1.6)
    white_balance: float = 0.2
    gamma: tuple[float, float] = (0.6, 1.6)
    contrast: tuple[float, float] = (0.6, 1.4)
    blur_sigma_px: tuple[float, float] = (0.3, 1.5)
    blur_prob: float = 0.5
    noise_sigma: tuple[float, float] = (1.0, 8.0)
    jpeg_quality: tuple[int, int] = (40, 95)
    jpeg_prob: float = 0.5
    grey_prob: float = 0.1

    def __post_init__(self) -> None:
        for name in ('exposure', 'gamma', 'contrast', 'blur_sigma_px', 'noise_sigma',
                     'jpeg_quality'):
            lo, hi = getattr(self, name)
            if not 0 <= lo <= hi:
                raise ValueError(f'{name} must be (min, max) with 0 <= min <= max, got {lo, hi}')
        for name in ('blur_prob', 'jpeg_prob', 'grey_prob'):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f'{name} must be in [0, 1], got {getattr(self, name)}')
        if not 0.0 <= self.white_balance < 1.0:
            raise ValueError(f'white_balance must be in [0, 1), got {self.white_balance}')
        if self.jpeg_quality[1] > 100:
            raise ValueError('jpeg_quality must lie within [0, 100]')


def photometric(rgb: np.ndarray, rng: np.random.Generator, *,
                params: PhotometricParams = PhotometricParams()) -> np.ndarray:
    """One random camera response applied to an image.

    Args:
        rgb: (H, W, 3) uint8 RGB image.
        rng: the random generator.
        params: the ranges.

    Returns:
        (H, W, 3) uint8 RGB: exposure, white balance, gamma, contrast, then optional blur,
        sensor noise, desaturation and a JPEG round trip.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise ValueError(f'rgb must be (H, W, 3) uint8, got {rgb.shape} {rgb.dtype}')
    p = params
    image: np.ndarray = rgb.astype(np.float32) / 255.0
    gains = rng.uniform(*p.exposure) * np.array(
        [1.0 + rng.uniform(-p.white_balance, p.white_balance), 1.0,
         1.0 + rng.uniform(-p.white_balance, p.white_balance)], np.float32)
    image = np.clip(image * gains, 0.0, 1.0) ** rng.uniform(*p.gamma)
    mean = float(image.mean())
    image = (image - mean) * rng.uniform(*p.contrast) + mean
    if rng.random() < p.blur_prob:
        image = cv2.GaussianBlur(image, (0, 0), rng.uniform(*p.blur_sigma_px))
    image = image + rng.normal(0.0, rng.uniform(*p.noise_sigma) / 255.0,
                               image.shape).astype(np.float32)
    if rng.random() < p.grey_prob:
        grey = image.mean(axis=2, keepdims=True)
        image = grey + rng.uniform(0.0, 0.5) * (image - grey)
    out = (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)
    if rng.random() < p.jpeg_prob:
        quality = int(rng.integers(p.jpeg_quality[0], p.jpeg_quality[1] + 1))
        ok, data = cv2.imencode('.jpg', out, [cv2.IMWRITE_JPEG_QUALITY, quality])
        if ok:
            out = cv2.imdecode(data, cv2.IMREAD_UNCHANGED)
    return out


def loose_box(box: Sequence[float], rng: np.random.Generator, *, grow: tuple[float, float] =
              (0.0, 0.25), shift: float = 0.1) -> tuple[int, int, int, int]:
    """A box as a localiser might cut around a part: grown and shifted at random.

    Args:
        box: (x, y, w, h) tight box of the part in pixels.
        rng: the random generator.
        grow: (min, max) relative growth of each side.
        shift: largest shift of the centre, relative to the side.

    Returns:
        (x, y, w, h) ints, w and h >= 1 (may reach outside the image: crops pad there).
    """
    x, y, w, h = (float(v) for v in box)
    if w <= 0 or h <= 0:
        raise ValueError(f'box must have positive width and height, got {tuple(box)}')
    new_w = w * (1.0 + rng.uniform(*grow))
    new_h = h * (1.0 + rng.uniform(*grow))
    cx = x + w / 2.0 + rng.uniform(-shift, shift) * w
    cy = y + h / 2.0 + rng.uniform(-shift, shift) * h
    return (int(round(cx - new_w / 2.0)), int(round(cy - new_h / 2.0)),
            max(int(round(new_w)), 1), max(int(round(new_h)), 1))


def texture_background(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1]: a random table surface.

    One of: a flat colour, smooth blotches (paper, cloth), a wood-like grain of stretched
    noise at a random angle, or a linear gradient; all with fine noise on top.
    """
    h, w = shape
    base = rng.uniform(0.05, 0.9) * (1.0 + rng.uniform(-0.15, 0.15, 3))
    kind = rng.integers(4)
    if kind == 0:
        field: np.ndarray = np.zeros((h, w), np.float32)
    elif kind == 1:
        field = cast(np.ndarray, cv2.GaussianBlur(
            rng.normal(0.0, 1.0, (h, w)).astype(np.float32), (0, 0), rng.uniform(2.0, 12.0)))
        field /= max(float(field.std()), 1e-6)
        field *= rng.uniform(0.03, 0.15)
    elif kind == 2:
        side = int(np.ceil(np.hypot(h, w))) + 2
        grain: np.ndarray = rng.normal(0.0, 1.0, (side, max(side // 12, 2))).astype(np.float32)
        grain = cv2.resize(grain, (side, side), interpolation=cv2.INTER_LINEAR)
        grain = cv2.GaussianBlur(grain, (0, 0), rng.uniform(0.5, 2.0))
        M = cv2.getRotationMatrix2D((side / 2.0, side / 2.0), rng.uniform(0.0, 180.0), 1.0)
        grain = cv2.warpAffine(grain, M, (side, side))
        top, left = (side - h) // 2, (side - w) // 2
        field = grain[top:top + h, left:left + w]
        field = field / max(float(field.std()), 1e-6) * rng.uniform(0.04, 0.15)
    else:
        yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
        angle = rng.uniform(0.0, 2.0 * np.pi)
        ramp = xx * np.cos(angle) + yy * np.sin(angle)
        field = (ramp - ramp.mean()) / max(float(np.ptp(ramp)), 1.0) * rng.uniform(0.1, 0.5)
    image = base[None, None, :] + field[..., None]
    image = image + rng.normal(0.0, rng.uniform(0.005, 0.03), (h, w, 1))
    return cast(np.ndarray, np.clip(image, 0.0, 1.0).astype(np.float32))
