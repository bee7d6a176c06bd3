"""A RealSense-like depth image made from a clean rendered depth, for
scripts/other_renderer_scenes.py: a model of its own, written without looking at
tlessbot_ros/sim/noise.py's code (its steps and values differ; docs/bench/other-renderer.md).

Steps, on the colour camera's z-depth (metres, 0 = nothing):

1. To disparity ``d = f * B / z`` (D415: B = 55 mm, f = the IR focal length in pixels).
2. Matching noise in disparity, spatially correlated over the matching window (a Gaussian
   field, sigma ``disparity_sigma_px``), then quantisation to ``1 / subpixel_steps`` pixel.
3. The second imager's occlusions: a pixel that a nearer pixel to its right hides from an
   imager ``B`` to the right gets no depth (a scan-line test on the disparities).
4. Edge fattening: the matching window straddling a depth edge gives the near surface's
   disparity to background pixels next to it (up to ``fattening_px``).
5. Grazing surfaces (view ray to surface normal above ``grazing_deg``) and the highlights of
   shiny (metal) parts, where the projector's pattern is reflected away, lose depth in blobs.
6. Edge-preserving smoothing over ~10 px (a bilateral filter in disparity): real D435i /
   D415 depth is smoothed so (docs/bench/real-pose-gap.md section 1).
7. Back to depth, 1 mm uint16 (0 = invalid).

As a command it applies the model, with fields changed, to a scenes folder written with
``--depth clean`` (an ablation without rendering again; metal parts from its
other_renderer.json, their highlights where the colour image is bright)::

    python scripts/other_renderer_depth.py CLEAN OUT [NAME=VALUE ...]
"""
from __future__ import annotations

import json
import shutil
import sys
from dataclasses import dataclass, fields, replace
from pathlib import Path

import cv2
import numpy as np


@dataclass(frozen=True)
class StereoDepthParams:
    """The depth model's settings (D415-like)."""

    # stereo baseline (m) and IR focal length (px) that turn depth into disparity
    baseline_m: float = 0.055
    ir_focal_px: float = 615.0
    # matching noise (px RMS of disparity) and the size of its correlation (px)
    disparity_sigma_px: float = 0.06
    noise_correlation_px: float = 3.0
    # subpixel steps per pixel of disparity (the ASIC's disparity quantisation)
    subpixel_steps: int = 16
    # background pixels next to a nearer surface that take its disparity (window half-width)
    fattening_px: int = 2
    # a disparity jump (px) counted as a depth edge for fattening
    edge_jump_px: float = 1.5
    # surfaces seen more obliquely than this (deg from the view ray) lose depth with
    # probability grazing_dropout
    grazing_deg: float = 78.0
    grazing_dropout: float = 0.7
    # shiny pixels (the caller's highlights of metal parts) lose depth with this probability
    highlight_dropout: float = 0.8
    # bilateral smoothing: window diameter (px), spatial sigma (px), disparity sigma (px)
    smooth_diameter_px: int = 11
    smooth_sigma_space_px: float = 4.0
    smooth_sigma_disparity_px: float = 0.4


def _correlated_noise(shape: tuple[int, int], sigma: float, correlation_px: float,
                      rng: np.random.Generator) -> np.ndarray:
    """A zero-mean Gaussian field of RMS ``sigma`` smooth over ``correlation_px``."""
    field = rng.normal(0.0, 1.0, shape).astype(np.float32)
    if correlation_px > 0:
        field = cv2.GaussianBlur(field, (0, 0), correlation_px)
        field /= max(float(field.std()), 1e-9)
    return field * np.float32(sigma)


def _occluded_in_second_imager(disparity: np.ndarray) -> np.ndarray:
    """(H, W) bool: pixels that a nearer pixel to their right hides from the second imager,
    which sees pixel u at ``u - d(u)``."""
    height, width = disparity.shape
    columns = np.arange(width, dtype=np.float32)[None, :]
    seen_at = np.where(disparity > 0, columns - disparity, np.inf)
    # the leftmost landing spot of every pixel to the right (running min from the right)
    right_min = np.minimum.accumulate(seen_at[:, ::-1], axis=1)[:, ::-1]
    shifted = np.concatenate([right_min[:, 1:], np.full((height, 1), np.inf)], axis=1)
    return (disparity > 0) & (seen_at > shifted + 0.5)


def _fatten_edges(disparity: np.ndarray, width_px: int, jump_px: float) -> np.ndarray:
    """Background pixels within ``width_px`` of a nearer surface take its disparity."""
    if width_px <= 0:
        return disparity
    kernel = np.ones((1, 2 * width_px + 1), np.uint8)   # the matching runs along rows
    nearest = cv2.dilate(disparity, kernel)
    fattened = (nearest - disparity > jump_px) & (disparity > 0)
    return np.where(fattened, nearest, disparity)


def _normals_cosine(z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(H, W) |cos| of the angle between the view ray and the surface normal of depth ``z``."""
    height, width = z.shape
    u, v = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    x = (u - K[0, 2]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    points = np.stack([x, y, z], axis=-1)
    du = np.gradient(points, axis=1)
    dv = np.gradient(points, axis=0)
    normal = np.cross(du, dv)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True) + 1e-12
    ray = points / (np.linalg.norm(points, axis=-1, keepdims=True) + 1e-12)
    return np.abs(np.sum(normal * ray, axis=-1))


def _blobs(mask: np.ndarray, probability: float, rng: np.random.Generator) -> np.ndarray:
    """Seeds drawn in ``mask`` with ``probability``, grown into 3x3 blobs inside it."""
    seeds = mask & (rng.random(mask.shape) < probability)
    grown = cv2.dilate(seeds.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    return grown & mask


def stereo_depth_mm(z_m: np.ndarray, shiny: np.ndarray, K: np.ndarray,
                    rng: np.random.Generator,
                    params: StereoDepthParams = StereoDepthParams()) -> np.ndarray:
    """RealSense-like depth of a clean z-depth image.

    Args:
        z_m: (H, W) float z-depth in metres along the optical axis, 0 where nothing is seen.
        shiny: (H, W) bool highlights on shiny (metal) surfaces.
        K: (3, 3) camera matrix of the image.
        rng: random numbers (the caller seeds it per frame and camera).

    Returns:
        (H, W) uint16 depth in millimetres, 0 = invalid.
    """
    z = np.asarray(z_m, np.float32)
    valid = z > 0
    fb = np.float32(params.ir_focal_px * params.baseline_m)
    disparity = np.where(valid, fb / np.maximum(z, 1e-6), 0).astype(np.float32)
    occluded = _occluded_in_second_imager(disparity)
    cosine = _normals_cosine(np.where(valid, z, np.nan), K)
    grazing = valid & (np.nan_to_num(cosine, nan=0.0)
                       < np.cos(np.radians(params.grazing_deg)))
    highlight = valid & shiny
    disparity = _fatten_edges(disparity, params.fattening_px, params.edge_jump_px)
    noise = _correlated_noise(z.shape, params.disparity_sigma_px,
                              params.noise_correlation_px, rng)
    disparity = np.where(disparity > 0, disparity + noise, 0).astype(np.float32)
    step = np.float32(1.0 / params.subpixel_steps)
    disparity = np.round(disparity / step) * step
    holes = (occluded | _blobs(grazing, params.grazing_dropout / 3, rng)
             | _blobs(highlight, params.highlight_dropout / 3, rng))
    disparity[holes] = 0
    # the range kernel (0.4 px) keeps holes (disparity 0) and far surfaces out of each mean
    smoothed = disparity if params.smooth_diameter_px <= 0 else cv2.bilateralFilter(
        disparity, params.smooth_diameter_px, params.smooth_sigma_disparity_px,
        params.smooth_sigma_space_px)
    out = np.where((disparity > 0) & (smoothed > 0), fb / np.maximum(smoothed, 1e-6), 0)
    return np.clip(np.rint(out * 1000.0), 0, 65535).astype(np.uint16)


def redepth(clean: Path, out: Path, params: StereoDepthParams, *, highlight: int = 235) -> None:
    """Copy the scenes folder ``clean`` to ``out`` with this model's depth (see the module)."""
    shutil.copytree(clean, out)
    drawn = json.loads((clean / 'other_renderer.json').read_text())
    for k, camera in enumerate(sorted(p.name for p in out.glob('test_*'))):
        folder = out / camera / '000000'
        cameras = json.loads((folder / 'scene_camera.json').read_text())
        for im, entry in cameras.items():
            name = f'{int(im):06d}.png'
            z = cv2.imread(str(folder / 'depth' / name), cv2.IMREAD_UNCHANGED) / 1000.0
            grey = cv2.imread(str(folder / 'rgb' / name)).min(axis=-1)
            shiny = np.zeros(z.shape, bool)
            for j, material in enumerate(drawn[im]['materials']):
                mask = cv2.imread(str(folder / 'mask_visib' / f'{int(im):06d}_{j:06d}.png'), 0)
                if material == 'metal' and mask is not None:
                    shiny |= (mask > 0) & (grey >= highlight)
            rng = np.random.default_rng([int(im), k])
            K = np.array(entry['cam_K']).reshape(3, 3)
            cv2.imwrite(str(folder / 'depth' / name), stereo_depth_mm(z, shiny, K, rng, params))


if __name__ == '__main__':
    names = {f.name: f.type for f in fields(StereoDepthParams)}
    changes = dict(a.split('=', 1) for a in sys.argv[3:])
    if set(changes) - set(names):
        raise SystemExit(f'unknown fields {sorted(set(changes) - set(names))}; know {names}')
    params = replace(StereoDepthParams(), **{k: (int if names[k] == 'int' else float)(v)
                                               for k, v in changes.items()})
    redepth(Path(sys.argv[1]), Path(sys.argv[2]), params)
