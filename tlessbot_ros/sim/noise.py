"""D415-like depth noise and colour sensor noise.

Two depth models: ``DepthNoiseParams.kind = 'per_pixel'`` (the default, below) and
``'smoothed'``, stereo-like depth as a real RealSense gives it (correlated disparity noise,
sub-pixel steps, edge fattening, edge-preserving smoothing:
:mod:`~tlessbot_ros.sim.stereo_depth`); both share the holes (shadow, highlights, random) but
for edge dropout.

Per-pixel model (all on a depth image aligned to colour, metres in, uint16 millimetres out):

* **Axial noise.** Stereo depth error grows with the square of the distance:
  ``sigma_z = scale * z^2 * sigma_subpixel / (f_ir_px * baseline_m)``, where ``f_ir_px`` is the
  focal length of the IR stereo pair (``ir_focal_px``; independent of the size of the colour
  image the depth is aligned to). With the D415's 55 mm baseline, f_ir ~ 615 px and
  ``sigma_subpixel = 0.07`` px this gives 2.1 mm RMS at 1 m (0.2 % of z, inside Intel's
  "<= 2 % at 2 m" spec and close to measured D415 numbers), 0.5 mm at 0.5 m.
  Half of the variance is spatially correlated (stereo matching windows), half is per pixel;
  slanted surfaces get up to 3x more (``1 / max(cos(incidence), 1/3)``).
* **Quantisation** to 1 mm (the 16UC1 depth unit).
* **Depth edges.** Pixels next to a depth jump larger than ``edge_jump_m + edge_jump_rel * z``
  become invalid with probability ``edge_dropout`` (flying pixels are removed by the sensor's
  filters; they show as a ragged invalid band).
* **Projector / stereo shadow.** The second imager sits ``baseline_m`` along +x of the depth
  origin; surface points it cannot see (occluded along the scan line) get no depth. The test is
  exact on the rendered depth: a pixel is shadowed if a pixel to its right maps to the left of it
  in the other view.
* **Holes on shiny surfaces.** Where the colour shading shows a strong specular highlight, depth
  drops out with probability ``ir_dropout * highlight`` (per material), grown into small blobs,
  plus sparse random holes everywhere (``random_holes``).

``DepthNoiseParams.scale`` multiplies sigma and every dropout probability (the robustness run of
the pose benchmark uses ``scale=2``: "sigma x 2, more holes"). ``scale=0`` gives clean,
quantised depth.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from tlessbot_ros.sim.stereo_depth import StereoDepthParams, smoothed_depth

DEPTH_KINDS = ('per_pixel', 'smoothed')


@dataclass(frozen=True)
class DepthNoiseParams:
    """Parameters of the D415-like depth noise (see the module docstring).

    ``kind`` picks the model: 'per_pixel' (default) or 'smoothed' (stereo-like, its settings in
    ``stereo``); the other fields serve both but ``sigma_subpixel``, ``correlated_share``,
    ``correlation_px`` and the edge dropout fields, which are the per-pixel kind's.
    """

    scale: float = 1.0
    sigma_subpixel: float = 0.07
    ir_focal_px: float = 615.0
    baseline_m: float = 0.055
    correlated_share: float = 0.5
    correlation_px: int = 4
    edge_jump_m: float = 0.004
    edge_jump_rel: float = 0.01
    edge_dropout: float = 0.6
    random_holes: float = 0.0003
    highlight_threshold: float = 0.35
    min_depth_m: float = 0.16
    max_depth_m: float = 10.0
    projector_shadow: bool = True
    kind: str = 'per_pixel'
    stereo: StereoDepthParams = field(default_factory=StereoDepthParams)

    def __post_init__(self) -> None:
        if self.kind not in DEPTH_KINDS:
            raise ValueError(f'unknown depth kind {self.kind!r}; choose from {DEPTH_KINDS}')


def spread_depth_kind(index: int, smoothed_share: float) -> str:
    """The depth kind of item ``index`` (a training view or scene, 0, 1, 2, ...) when a share
    ``smoothed_share`` (0-1) of the items gets the 'smoothed' kind, spread evenly over the
    indices: item k is smoothed when ``floor((k + 1) * share) > floor(k * share)``. Depends on
    the index alone, so it draws no random numbers and any subset of items keeps its kinds."""
    if not 0.0 <= smoothed_share <= 1.0:
        raise ValueError(f'smoothed_share must be in [0, 1], got {smoothed_share}')
    smoothed = int((index + 1) * smoothed_share) > int(index * smoothed_share)
    return 'smoothed' if smoothed else 'per_pixel'


def stereo_region(mask: np.ndarray, depth_m: np.ndarray, K: np.ndarray,
                  T_world_camera: np.ndarray, *, grow_px: int = 1,
                  min_height_m: float = 0.002) -> np.ndarray:
    """A part's region as a localiser cuts it from stereo-like depth: ``mask`` grown by up to
    ``grow_px`` pixels into the table around it wherever the depth stands more than
    ``min_height_m`` above the table (the fattened edge gives the table beside a part the
    part's disparity, :mod:`~tlessbot_ros.sim.stereo_depth`).

    Args:
        mask: (H, W) bool visible silhouette of the part.
        depth_m: (H, W) float z-depth in metres, 0 = invalid.
        K: (3, 3) camera matrix of the image; T_world_camera: (4, 4) camera pose on the table
            (world z = 0 is the table, z up).

    Returns:
        (H, W) bool region, a superset of ``mask``.
    """
    from tlessbot_ros.core.localise.cues import height_above_table

    if grow_px <= 0:
        return mask
    size = 2 * int(grow_px) + 1
    ring = cv2.dilate(mask.astype(np.uint8), np.ones((size, size), np.uint8)) > 0
    high = np.nan_to_num(height_above_table(depth_m, K, T_world_camera), nan=-1.0)
    return np.asarray(mask | (ring & (high > min_height_m)))


def depth_sigma_m(depth_m: np.ndarray, params: DepthNoiseParams) -> np.ndarray:
    """Axial standard deviation (metres) at depth ``depth_m`` (any shape) before slant/scale."""
    return depth_m ** 2 * params.sigma_subpixel / (params.ir_focal_px * params.baseline_m)


def stereo_shadow(depth_m: np.ndarray, focal_px: float, baseline_m: float) -> np.ndarray:
    """(H, W) bool: pixels the second imager (``baseline_m`` along +x) cannot see.

    A point at column u and depth z appears at ``u' = u - f * b / z`` in the other view. Scanning
    each row right to left, the point is occluded when some pixel to its right lands at or left
    of ``u'`` (it is nearer, so it hides the point). Pixels without depth never occlude.
    """
    h, w = depth_m.shape
    valid = depth_m > 0
    u = np.arange(w, dtype=np.float32)[None, :]
    target = np.where(valid, u - focal_px * baseline_m / np.where(valid, depth_m, 1.0), np.inf)
    # Minimum over the pixels strictly to the right.
    rev_min = np.minimum.accumulate(target[:, ::-1], axis=1)[:, ::-1]
    right_min = np.empty_like(rev_min)
    right_min[:, :-1] = rev_min[:, 1:]
    right_min[:, -1] = np.inf
    return valid & (right_min < target - 0.5)


def depth_edges(depth_m: np.ndarray, params: DepthNoiseParams) -> np.ndarray:
    """(H, W) bool: pixels with a neighbour more than the jump threshold nearer or farther."""
    d = depth_m.astype(np.float32)
    big = cv2.dilate(d, np.ones((3, 3), np.uint8))
    small = cv2.erode(d, np.ones((3, 3), np.uint8))
    jump = np.maximum(big - d, d - small)
    return (d > 0) & (jump > params.edge_jump_m + params.edge_jump_rel * d)


def _blobs(seeds: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Grow single-pixel holes into 1-3 px blobs (each neighbour joins with probability 1/2)."""
    if not seeds.any():
        return seeds
    grown = cv2.dilate(seeds.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    grown &= ~seeds
    rows, cols = np.nonzero(grown)
    keep = rng.random(len(rows)) < 0.5
    out = seeds.copy()
    out[rows[keep], cols[keep]] = True
    return out


def _shared_holes(rng: np.random.Generator, params: DepthNoiseParams,
                  highlight: np.ndarray | None, ir_dropout: np.ndarray | None,
                  shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool holes of the smoothed kind: sparse random ones and strong highlights, grown
    into small blobs (the per-pixel kind draws the same, interleaved with its edge dropout)."""
    holes = rng.random(shape, dtype=np.float32) < params.random_holes * params.scale
    _add_highlight_holes(holes, rng, params, highlight, ir_dropout)
    return _blobs(holes, rng)


def _add_highlight_holes(holes: np.ndarray, rng: np.random.Generator, params: DepthNoiseParams,
                         highlight: np.ndarray | None, ir_dropout: np.ndarray | None) -> None:
    """Mark in ``holes`` the pixels whose strong specular highlight drops their depth."""
    if highlight is None or ir_dropout is None:
        return
    rows, cols = np.nonzero((highlight > params.highlight_threshold) & (ir_dropout > 0))
    strong = ((highlight[rows, cols] - params.highlight_threshold)
              / (1.0 - params.highlight_threshold))
    p = np.clip(ir_dropout[rows, cols] * strong * params.scale * 4.0, 0, 1)
    hit = rng.random(len(rows)) < p
    holes[rows[hit], cols[hit]] = True


def add_depth_noise(depth_m: np.ndarray, focal_px: float, rng: np.random.Generator,
                    params: DepthNoiseParams = DepthNoiseParams(), *,
                    cos_incidence: np.ndarray | None = None,
                    highlight: np.ndarray | None = None,
                    ir_dropout: np.ndarray | None = None) -> np.ndarray:
    """Noisy D415-like depth image.

    Args:
        depth_m: (H, W) float32 clean z-depth in metres, 0 = no surface.
        focal_px: horizontal focal length of the (aligned) depth image in pixels (for the
            stereo shadow, drawn in image coordinates).
        rng: random generator (the result is a deterministic function of its state).
        params: noise model parameters.
        cos_incidence: (H, W) cosine between the surface normal and the viewing ray (1 = facing
            the camera), or None (treated as 1).
        highlight: (H, W) specular highlight strength in [0, 1] from the shading, or None.
        ir_dropout: (H, W) per-pixel dropout probability at full highlight (from the material).

    Returns:
        (H, W) uint16 depth in millimetres, 0 = invalid.
    """
    depth_m = np.asarray(depth_m, dtype=np.float32)
    if depth_m.ndim != 2:
        raise ValueError(f'depth must be (H, W), got shape {depth_m.shape}')
    h, w = depth_m.shape
    valid = (depth_m >= params.min_depth_m) & (depth_m <= params.max_depth_m)
    s = float(params.scale)
    if params.kind == 'smoothed' and s > 0:
        holes = ~valid | _shared_holes(rng, params, highlight, ir_dropout, (h, w))
        if params.projector_shadow and params.baseline_m > 0:
            holes |= stereo_shadow(depth_m, focal_px, params.baseline_m)
        return smoothed_depth(depth_m, focal_px, rng, params, holes)
    noisy = depth_m.copy()
    if s > 0:
        sigma = depth_sigma_m(depth_m, params) * s
        if cos_incidence is not None:
            sigma = sigma / np.maximum(np.abs(cos_incidence), 1.0 / 3.0)
        white = rng.standard_normal((h, w), dtype=np.float32)
        c = params.correlation_px
        coarse = rng.standard_normal((h // c + 2, w // c + 2), dtype=np.float32)
        smooth = cv2.resize(coarse, (w + 2 * c, h + 2 * c), interpolation=cv2.INTER_LINEAR)
        smooth = smooth[c:c + h, c:c + w]
        smooth /= max(float(smooth[::3, ::3].std()), 1e-6)
        a = np.sqrt(params.correlated_share)
        b = np.sqrt(1.0 - params.correlated_share)
        noisy = depth_m + sigma * (a * smooth + b * white)
        # One uniform draw serves edge dropout (low end) and random holes (high end).
        u = rng.random((h, w), dtype=np.float32)
        drop = depth_edges(depth_m, params) & (u < min(1.0, params.edge_dropout * s))
        holes = u > 1.0 - params.random_holes * s
        _add_highlight_holes(holes, rng, params, highlight, ir_dropout)
        drop |= _blobs(holes, rng)
        valid &= ~drop
    if params.projector_shadow and params.baseline_m > 0:
        valid &= ~stereo_shadow(depth_m, focal_px, params.baseline_m)
    out = np.rint(np.where(valid, noisy, 0.0) * 1000.0)
    return np.clip(out, 0, 65535).astype(np.uint16)


def _gaussian_quantiles(levels: int = 256) -> np.ndarray:
    """``levels`` equiprobable standard-normal values (inverse CDF at bin centres)."""
    from scipy.special import ndtri

    q = ndtri((np.arange(levels) + 0.5) / levels)
    return (q / q.std()).astype(np.float32)


_QUANTILES = _gaussian_quantiles()


def add_colour_noise(rgb: np.ndarray, rng: np.random.Generator, *, sigma: float = 1.5,
                     blur_sigma_px: float = 0.6) -> np.ndarray:
    """Blur (lens/demosaicing) and Gaussian read noise on an (H, W, 3) uint8 image; uint8 out.

    The noise is drawn as uint8 indices into 256 equiprobable Gaussian quantiles (much cheaper
    than a float normal per channel; the distribution is the same to within display precision).
    """
    img = cv2.GaussianBlur(rgb, (0, 0), blur_sigma_px) if blur_sigma_px > 0 else rgb
    if sigma <= 0:
        return np.ascontiguousarray(img, dtype=np.uint8)
    noise = (_QUANTILES * np.float32(sigma))[rng.integers(0, 256, img.shape, dtype=np.uint8)]
    noise += img
    noise += np.float32(0.5)
    return np.clip(noise, 0, 255).astype(np.uint8)
