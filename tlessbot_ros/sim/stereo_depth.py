"""Smoothed, stereo-like depth: the ``'smoothed'`` kind of
:class:`~tlessbot_ros.sim.noise.DepthNoiseParams`.

Real RealSense D4xx depth is not per-pixel noisy but smoothed (docs/bench/real-pose-gap.md
section 1, docs/bench/smoothed-sim-depth.md): the ASIC matches a window of the two IR images
along the rows, so its error lives in disparity, is correlated over the window and comes in
sub-pixel steps; the window straddling a depth edge gives the nearer surface's disparity to the
background next to it (edge fattening); and the camera's edge-preserving filter smooths what is
left over ~10 px. Steps, on the colour camera's z-depth (metres, 0 = nothing):

1. To disparity ``d = f_ir * B / z`` (``DepthNoiseParams.ir_focal_px`` and ``baseline_m``).
2. Edge fattening: pixels within ``fattening_px`` of a surface nearer by more than
   ``edge_jump_px`` of disparity take its disparity.
3. Matching noise: a Gaussian field of RMS ``disparity_sigma_px`` (times ``scale``), smooth
   over ``correlation_px``; then quantisation to ``1 / subpixel_steps`` px.
4. Holes: the second imager's shadow, strong specular highlights and sparse random holes
   (as the per-pixel kind, :func:`~tlessbot_ros.sim.noise.add_depth_noise`).
5. Edge-preserving smoothing: a bilateral filter in disparity (range ``smooth_sigma_px``
   keeps holes and far surfaces out of each mean).
6. Back to depth, 1 mm steps (uint16 millimetres, 0 = invalid).

Image-domain lengths (correlation, fattening, smoothing) are in IR pixels and scale with
``focal_px / ir_focal_px`` on the aligned image. The noise and its correlation are set so
that the depth's noise on a table and its correlation length match the real D435i frames, the
smoothing's range so that their steps of 0.6-2 px of disparity stay sharp
(docs/bench/smoothed-sim-depth.md); the sub-pixel steps, the fattening and the smoothing's
spatial sigma are the values of scripts/other_renderer_depth.py (docs/bench/other-renderer.md).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from tlessbot_ros.sim.noise import DepthNoiseParams


@dataclass(frozen=True)
class StereoDepthParams:
    """Settings of the smoothed, stereo-like depth (module docstring).

    Attributes:
        disparity_sigma_px: matching noise in disparity (px RMS) before the smoothing.
        correlation_px: Gaussian sigma (IR px) over which the matching noise is correlated.
        subpixel_steps: disparity steps per pixel (the matcher's sub-pixel resolution).
        fattening_px: background pixels this close (IR px) to a nearer surface take its
            disparity.
        edge_jump_px: a disparity difference (px) that the fattening counts as a depth edge.
        smooth_space_px: spatial sigma (IR px) of the bilateral smoothing; 0 turns it off.
        smooth_sigma_px: range sigma (px of disparity) of the bilateral smoothing.
    """

    disparity_sigma_px: float = 0.13
    correlation_px: float = 3.0
    subpixel_steps: int = 16
    fattening_px: float = 2.0
    edge_jump_px: float = 0.5
    smooth_space_px: float = 4.0
    smooth_sigma_px: float = 0.2


def _correlated_field(shape: tuple[int, int], correlation_px: float,
                      rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 zero-mean, unit-RMS Gaussian field, correlated over ``correlation_px``."""
    white = rng.standard_normal(shape, dtype=np.float32)
    if correlation_px <= 0:
        return white
    field = cv2.GaussianBlur(white, (0, 0), correlation_px, borderType=cv2.BORDER_REFLECT)
    return field / max(float(field.std()), 1e-9)


def _fattened(disparity: np.ndarray, radius_px: float, jump_px: float) -> np.ndarray:
    """``disparity`` where background pixels within ``radius_px`` of a surface nearer by more
    than ``jump_px`` take the nearest such disparity (the matching window's support)."""
    r = int(round(radius_px))
    if r <= 0:
        return disparity
    window = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    nearest = cv2.dilate(disparity, window)
    takes = (nearest - disparity > jump_px)
    return np.where(takes, nearest, disparity)


def smoothed_depth(depth_m: np.ndarray, focal_px: float, rng: np.random.Generator,
                   params: DepthNoiseParams, holes: np.ndarray) -> np.ndarray:
    """Smoothed stereo-like depth of a clean z-depth image (module docstring).

    Args:
        depth_m: (H, W) float32 clean z-depth in metres, 0 = no surface.
        focal_px: horizontal focal length of the aligned depth image in pixels.
        rng: random generator.
        params: the depth model (``params.stereo`` and the shared camera fields).
        holes: (H, W) bool pixels without depth (shadow, highlights, out of range).

    Returns:
        (H, W) uint16 depth in millimetres, 0 = invalid.
    """
    stereo = params.stereo
    s = float(params.scale)
    px = focal_px / params.ir_focal_px          # aligned-image pixels per IR pixel
    fb = np.float32(params.ir_focal_px * params.baseline_m)
    seen = depth_m > 0
    disparity = np.where(seen, fb / np.where(seen, depth_m, 1.0), 0.0).astype(np.float32)
    disparity = _fattened(disparity, stereo.fattening_px * px, stereo.edge_jump_px)
    if s > 0:
        noise = _correlated_field(depth_m.shape, stereo.correlation_px * px, rng)
        disparity += noise * np.float32(stereo.disparity_sigma_px * s)
        step = np.float32(1.0 / stereo.subpixel_steps)
        disparity = np.round(disparity / step) * step
    disparity[holes | ~seen] = 0.0
    if s > 0 and stereo.smooth_space_px > 0:
        sigma_space = stereo.smooth_space_px * px
        diameter = 2 * int(round(1.25 * sigma_space)) + 1
        smooth = cv2.bilateralFilter(disparity, diameter, stereo.smooth_sigma_px, sigma_space)
        disparity = np.where(disparity > 0, smooth, 0.0).astype(np.float32)
    valid = disparity > 0
    out = np.where(valid, fb / np.where(valid, disparity, 1.0), 0.0) * 1000.0
    return np.clip(np.rint(out), 0, 65535).astype(np.uint16)
