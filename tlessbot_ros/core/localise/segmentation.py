"""Colour segmentation of textureless parts on a table: watershed, HED, CIE-LAB, background.

This is the paper's §3.1 (Sensors 2020, "Marker-less 3D object recognition and 6D pose
estimation for homogeneous textureless objects") built from OpenCV operations so that one
640x480 view takes about 10 ms:

* **Histogram cut-offs.** Each cue channel (grey level, the three HED stains, the CIE-LAB
  chroma axes a and b), less a robust quadratic trend (uneven lighting), gets a cut-off read
  from its histogram: the background is the dominant peak; pixels further than
  ``cutoff_sigma`` robust standard deviations (and at least the channel's ``*_floor``) from it
  are object candidates, pixels beyond ``sure_sigma`` are sure
  object markers. With an empty-table image the same cut-offs are read on the difference to
  it, which makes patterned tables as easy as plain ones (the paper's "first guess").
* **HED colour deconvolution** (Ruifrok & Johnston, Anal. Quant. Cytol. Histol. 23(4), 2001)
  through a 256-entry optical-density lookup table and one ``cv2.transform`` with the same
  stain matrix as ``skimage.color.rgb2hed``: dark parts stand out in H, light ones in E.
* **CIE-LAB** (``cv2.cvtColor`` on float RGB, true L in [0, 100]): translucent light-yellow
  parts stand out on the b (yellow) axis, pink on a.
* **Background subtraction** against an empty-table image: colour distance in LAB with a
  shadow test (a cast shadow darkens the table but keeps its chromaticity).
* **Watershed.** The union of the cues gives markers (sure object = union cores, sure
  background = pixels far from every candidate); ``cv2.watershed`` floods between them.
  OpenCV floods the largest absolute neighbour difference of its input; we feed it the image
  smoothed by the 3x3 binomial kernel, so the flooded relief is the 3x3 Sobel gradient
  magnitude (Sobel = binomial smoothing followed by a central difference).
* **Instances.** Connected components, small-blob removal (``min_area_px``) and touching-object
  separation: the distance transform of a blob is cut at a fraction of its maximum; two or more
  cores seed a second watershed that divides the blob.

All images are (H, W, 3) uint8 RGB. Labels are (H, W) uint16 with 0 = background. Boxes are
(x, y, w, h) int32 pixels, the usual OpenCV / BOP ``bbox`` convention.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace

import cv2
import numpy as np

from tlessbot_ros.core.common import pixel_counts
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
    return np.repeat(od.reshape(256, 1, 1), 3, axis=2).reshape(1, 256, 3).copy()


_OD_LUTS: dict[int, np.ndarray] = {}

_LAB8_TO_LAB = np.array([[100.0 / 255.0, 0, 0, 0], [0, 1, 0, -128], [0, 0, 1, -128]], np.float32)

METHODS = ('watershed', 'hed', 'lab', 'background', 'depth')


@dataclass(frozen=True)
class SegmentationParams:
    """Tuning of :func:`segment`. Defaults were chosen on simulated two-view scenes.

    Attributes:
        methods: cues whose union forms the foreground; any of ``METHODS``. 'watershed' adds
            the grey-level histogram extremes as markers *and* refines the union by flooding;
            without it the union is used as is. 'background' is used only when an empty-table
            image is given, 'depth' only when an aligned depth image and the camera pose are
            given (leave 'depth' out for the paper's RGB-only method).
        cutoff_sigma: candidate cut-off, in robust standard deviations of the background peak.
        sure_sigma: sure-object marker cut-off (histogram extreme), same unit.
        grey_floor, hed_floor, lab_floor: smallest cut-off distance from the background peak
            per channel (grey in L units 0-100, HED in optical-density units, a/b in LAB
            units); stops sensor noise on a very plain table from becoming objects.
        hed_dark_level: intensities below this are clamped before the HED logarithm, so the
            noise of near-black pixels does not swamp the stain channels.
        border_fraction: the background peak of each histogram is read from a frame of this
            width (fraction of the image size) along the image border, where the table is;
            0 uses the whole image.
        background_delta_e: LAB distance to the empty-table image above which a pixel differs.
        shadow_ratio: (low, high) brightness ratio to the empty table treated as a cast shadow
            when the chromaticity also stays within ``shadow_chroma``.
        shadow_chroma: largest a/b change (LAB units) of a shadowed table pixel.
        band_px: the watershed decides only within this distance of a candidate pixel.
        min_area_px: blobs smaller than this (pixels) are dropped.
        open_px: radius of the morphological opening that removes thin noise before labelling.
        split_touching: separate touching objects (distance transform + watershed).
        split_core_fraction: distance-transform cores are pixels above this fraction of the
            blob's largest distance; two or more cores mean two or more objects.
        split_min_core_px: cores smaller than this (pixels) are ignored.
        split_min_depth_px: largest distance of a blob (pixels) below which it is never split.
        cue_scale: image scale at which the colour cues are computed (1.0 = full resolution).
        colour_split_delta: a blob whose pixels form two chroma clusters (a / L, b / L, x100)
            further apart than this is divided between them first (touching parts of different
            materials); 0 disables.
        colour_split_min_share: smallest share of the blob for a colour piece (so specular
            highlights do not become parts).
        depth_min_height_m: depth cue: pixels whose back-projected point lies higher than
            this above the table plane (world z) are object candidates...
        depth_sure_height_m: ... and higher than this, sure object markers.
        depth_noise_k: both heights are raised to this many robust standard deviations of
            the table's measured height (the depth noise grows with distance).
        depth_table_height_m: pixels with valid depth lower than this (and lower than
            ``depth_noise_k / 2`` noise deviations) are table: colour candidates there are
            dropped (cast shadows, dark table squares) and they seed the watershed's
            background. Invalid depth (0 / NaN) votes for nothing, so the colour cues decide.
        depth_filter_px: aperture of the median filter on the height map (1 = none).
    """

    methods: tuple[str, ...] = METHODS
    cutoff_sigma: float = 5.0
    sure_sigma: float = 9.0
    grey_floor: float = 8.0
    hed_floor: float = 0.04
    lab_floor: float = 6.0
    hed_dark_level: int = 10
    border_fraction: float = 0.1
    background_delta_e: float = 12.0
    shadow_ratio: tuple[float, float] = (0.3, 0.97)
    shadow_chroma: float = 4.0
    band_px: int = 4
    min_area_px: int = 80
    open_px: int = 1
    split_touching: bool = True
    split_core_fraction: float = 0.55
    split_min_core_px: int = 12
    split_min_depth_px: float = 5.0
    cue_scale: float = 0.5
    colour_split_delta: float = 25.0
    colour_split_min_share: float = 0.12
    depth_min_height_m: float = 0.004
    depth_sure_height_m: float = 0.010
    depth_noise_k: float = 4.0
    depth_table_height_m: float = 0.0025
    depth_filter_px: int = 3

    def __post_init__(self) -> None:
        unknown = set(self.methods) - set(METHODS)
        if unknown or not self.methods:
            raise ValueError(f'methods must be a non-empty subset of {METHODS}, '
                             f'got {self.methods}')
        if not 0.0 < self.cutoff_sigma <= self.sure_sigma:
            raise ValueError('need 0 < cutoff_sigma <= sure_sigma, got '
                             f'{self.cutoff_sigma} and {self.sure_sigma}')
        if self.min_area_px < 1:
            raise ValueError(f'min_area_px must be >= 1, got {self.min_area_px}')
        if not 0.0 < self.split_core_fraction < 1.0:
            raise ValueError('split_core_fraction must be in (0, 1), got '
                             f'{self.split_core_fraction}')
        if not 0.0 <= self.border_fraction < 0.5:
            raise ValueError(f'border_fraction must be in [0, 0.5), got {self.border_fraction}')
        if not 0.0 < self.cue_scale <= 1.0:
            raise ValueError(f'cue_scale must be in (0, 1], got {self.cue_scale}')
        if not 0.0 < self.depth_min_height_m <= self.depth_sure_height_m:
            raise ValueError('need 0 < depth_min_height_m <= depth_sure_height_m, got '
                             f'{self.depth_min_height_m} and {self.depth_sure_height_m}')
        if self.depth_filter_px not in (1, 3, 5):
            raise ValueError(f'depth_filter_px must be 1, 3 or 5, got {self.depth_filter_px}')
        lo, hi = self.shadow_ratio
        if not 0.0 <= lo < hi <= 1.0:
            raise ValueError(f'shadow_ratio must satisfy 0 <= low < high <= 1, got '
                             f'{self.shadow_ratio}')


@dataclass
class Segmentation:
    """Result of :func:`segment` for one view.

    Attributes:
        labels: (H, W) uint16 instance labels, 0 = background, 1..N objects.
        boxes: (N, 4) int32 (x, y, w, h) of instance ``i + 1`` in row ``i``.
        areas: (N,) int64 pixel counts.
        foreground: (H, W) bool union mask before instance separation.
        cues: per-method bool candidate masks at ``params.cue_scale`` (for inspection).
        timings_ms: wall time per stage in milliseconds.
    """

    labels: np.ndarray
    boxes: np.ndarray
    areas: np.ndarray
    foreground: np.ndarray
    cues: dict[str, np.ndarray] = field(default_factory=dict)
    timings_ms: dict[str, float] = field(default_factory=dict)

    @property
    def count(self) -> int:
        return int(self.boxes.shape[0])


# --------------------------------------------------------------------------- colour spaces
def _check_rgb(rgb: np.ndarray, name: str = 'rgb') -> np.ndarray:
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
    rgb = _check_rgb(rgb)
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

    Computed by OpenCV's 8-bit conversion (4x faster than float input here) and rescaled, so
    values are quantised to 100/255 in L and 1 in a, b.
    """
    rgb = _check_rgb(rgb)
    lab8 = cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab)
    return cv2.transform(lab8.astype(np.float32), _LAB8_TO_LAB)


# --------------------------------------------------------------------------- histogram cut-offs
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
    gy, gx = np.mgrid[0:sample.shape[0], 0:sample.shape[1]]
    x = gx / max(sample.shape[1] - 1, 1) - 0.5
    y = gy / max(sample.shape[0] - 1, 1) - 0.5
    surface = (coef[0] + coef[1] * x + coef[2] * y + coef[3] * x * x + coef[4] * x * y
               + coef[5] * y * y).astype(np.float32)
    # The sample grid covers [step/2, ... ] pixel centres; resize spans the same range closely.
    surface = cv2.resize(surface, (w, h), interpolation=cv2.INTER_LINEAR)
    return channel - surface


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


# --------------------------------------------------------------------------- depth
_HEIGHT_COEF: dict[tuple, np.ndarray] = {}


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
class _DepthCue:
    candidate: np.ndarray  # object candidates (cue scale)
    sure: np.ndarray  # sure object
    table: np.ndarray  # valid depth on the table plane
    sigma_m: float  # robust height noise of the table


def _depth_cue(height: np.ndarray, params: SegmentationParams) -> _DepthCue:
    """Object / table masks from a (h, w) height map (NaN invalid)."""
    valid = ~np.isnan(height)
    filled = height.copy()
    filled[~valid] = 0.0
    sample = filled[::2, ::2][valid[::2, ::2]]
    sample = sample[np.abs(sample) < 0.02]
    sigma = 1.4826 * float(np.median(np.abs(sample))) if sample.size > 50 else 0.0
    if params.depth_filter_px > 1:
        filtered = cv2.medianBlur(filled, params.depth_filter_px)
    else:
        filtered = filled
    k = params.depth_noise_k
    low = max(params.depth_min_height_m, k * sigma)
    high = max(params.depth_sure_height_m, 1.5 * k * sigma)
    table_h = max(params.depth_table_height_m, 0.5 * k * sigma)
    # The median over a hole's neighbours fills it (invalid pixels count as table height, so
    # they never make an object on their own).
    candidate = filtered > low
    sure = filtered > high
    table = valid & (filtered < table_h) & (filled < table_h)
    return _DepthCue(candidate, sure, table, sigma)


# --------------------------------------------------------------------------- cues
def background_mask(rgb: np.ndarray, background: np.ndarray, *,
                    params: SegmentationParams = SegmentationParams(),
                    lab: np.ndarray | None = None,
                    background_lab: np.ndarray | None = None) -> np.ndarray:
    """Pixels that differ from the empty-table image, cast shadows excluded.

    Args:
        rgb, background: (H, W, 3) uint8 RGB of the scene and of the empty table (same camera
            and lighting).
        lab, background_lab: their LAB images if already computed.

    Returns:
        (H, W) bool.
    """
    rgb = _check_rgb(rgb)
    background = _check_rgb(background, 'background')
    if background.shape != rgb.shape:
        raise ValueError(f'background shape {background.shape} differs from image shape '
                         f'{rgb.shape}; it must come from the same camera and resolution')
    lab = rgb_to_lab(rgb) if lab is None else lab
    bg = rgb_to_lab(background) if background_lab is None else background_lab
    diff = lab - bg
    delta_e = np.sqrt(np.einsum('ijk,ijk->ij', diff, diff))
    changed = delta_e > params.background_delta_e
    shadow = _shadow(lab, bg, params)
    return changed & ~shadow


def hed_masks(hed: np.ndarray, params: SegmentationParams,
              *, reference: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Union of the H, E and D histogram cut-offs: (candidate, sure) (H, W) bool masks.

    With ``reference`` (the empty table's HED image) the cut-offs apply to the difference.
    """
    cand = np.zeros(hed.shape[:2], bool)
    sure = np.zeros(hed.shape[:2], bool)
    for c in range(3):
        channel = remove_trend(hed[..., c]) if reference is None else \
            hed[..., c] - reference[..., c]
        peak = None if reference is None else 0.0
        a, b = _cutoff_masks(channel, params.hed_floor, params, peak=peak)
        cand |= a
        sure |= b
    return cand, sure


def lab_masks(lab: np.ndarray, params: SegmentationParams,
              *, reference: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Chroma (a, b) histogram cut-offs: (candidate, sure) (H, W) bool masks."""
    cand = np.zeros(lab.shape[:2], bool)
    sure = np.zeros(lab.shape[:2], bool)
    for c in (1, 2):
        channel = remove_trend(lab[..., c]) if reference is None else \
            lab[..., c] - reference[..., c]
        peak = None if reference is None else 0.0
        a, b = _cutoff_masks(channel, params.lab_floor, params, peak=peak)
        cand |= a
        sure |= b
    return cand, sure


def sobel_magnitude(grey: np.ndarray) -> np.ndarray:
    """3x3 Sobel gradient magnitude, (H, W) float32, of an (H, W) image."""
    grey = np.asarray(grey, dtype=np.float32)
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3)
    return cv2.magnitude(gx, gy)


def watershed_refine(rgb: np.ndarray, candidate: np.ndarray, sure: np.ndarray, *,
                     band_px: int = 4, sure_background: np.ndarray | None = None) -> np.ndarray:
    """Marker-controlled watershed between sure-object and sure-background markers.

    Args:
        rgb: (H, W, 3) uint8 image to flood (smoothed here by the 3x3 binomial kernel so the
            relief is the Sobel gradient magnitude).
        candidate: (H, W) bool object candidates; pixels further than ``band_px`` from any
            candidate are sure background.
        sure: (H, W) bool sure-object pixels (markers).
        sure_background: optional (H, W) bool pixels known to be table (e.g. from depth);
            they become background markers too (sure-object pixels win where both hold).

    Returns:
        (H, W) bool object mask.
    """
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_px + 1, 2 * band_px + 1))
    out = np.zeros(candidate.shape, bool)
    if not sure.any():
        return out
    near = cv2.dilate(candidate.view(np.uint8), kernel)
    # Flood only the box around the candidates (the rest is background anyway).
    x, y, w, h = cv2.boundingRect(near)
    near_c = near[y:y + h, x:x + w].astype(bool)
    markers = np.zeros((h, w), np.int32)
    markers[~near_c] = 1
    if sure_background is not None:
        markers[sure_background[y:y + h, x:x + w]] = 1
    markers[sure[y:y + h, x:x + w]] = 2
    smooth = cv2.GaussianBlur(rgb[y:y + h, x:x + w], (3, 3), 0)
    markers = _watershed_padded(smooth, markers)
    # Watershed lines (-1) lie on the edge itself; they go to the background.
    out[y:y + h, x:x + w] = markers == 2
    return out


def _watershed_padded(image: np.ndarray, markers: np.ndarray) -> np.ndarray:
    """cv2.watershed without its artefact of marking the image's outer pixels as lines."""
    image = cv2.copyMakeBorder(image, 1, 1, 1, 1, cv2.BORDER_REPLICATE)
    padded = cv2.copyMakeBorder(markers, 1, 1, 1, 1, cv2.BORDER_REPLICATE)
    cv2.watershed(image, padded)
    return padded[1:-1, 1:-1]


# --------------------------------------------------------------------------- instances
def split_touching(mask: np.ndarray, rgb: np.ndarray | None = None, *,
                   params: SegmentationParams = SegmentationParams()) -> np.ndarray:
    """Label a foreground mask, dividing blobs whose distance transform has several cores.

    Blobs of several materials are first divided by colour (2-means on a / L, b / L); then
    a blob whose distance transform, cut at ``split_core_fraction`` of its maximum, has two
    or more cores is divided by a watershed seeded with them.

    Args:
        mask: (H, W) bool foreground.
        rgb: (H, W, 3) uint8 image; when given, the dividing lines follow its colour edges.

    Returns:
        (H, W) int32 labels, 0 = background, 1..N (blobs below ``min_area_px`` removed).
    """
    return _instances(mask, rgb, params)[0]


def _instances(mask: np.ndarray, rgb: np.ndarray | None,
               params: SegmentationParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(labels (H, W) int32, boxes (N, 4) int32, areas (N,) int64) of :func:`split_touching`.

    Blobs are labelled by one look-up; only blobs that may hold several parts (deep enough
    for a split) are looked at one by one, in a crop.
    """
    mask_u8 = np.ascontiguousarray(mask, dtype=np.uint8)
    n, comp, stats, _ = cv2.connectedComponentsWithStats(mask_u8, connectivity=8,
                                                         ltype=cv2.CV_32S)
    big = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= params.min_area_px) + 1
    H, W = mask.shape
    # pieces[i]: None = the blob stays whole; else (y0, x0, [bool piece masks in the crop]).
    pieces: dict[int, tuple[int, int, list[np.ndarray]]] = {}
    # A blob narrower than twice the smallest split depth has a distance transform below it.
    deep = 2.0 * params.split_min_depth_px
    for i in big if params.split_touching else ():
        x, y, w, h, area = (int(v) for v in stats[i])
        if min(w, h) < deep:
            continue
        x0, y0 = max(x - 1, 0), max(y - 1, 0)
        x1, y1 = min(x + w + 1, W), min(y + h + 1, H)
        blob = comp[y0:y1, x0:x1] == i
        crop = None if rgb is None else rgb[y0:y1, x0:x1]
        by_colour = [blob] if crop is None or params.colour_split_delta <= 0 else \
            _colour_pieces(blob, crop, params)
        found = []
        for piece_mask in by_colour:
            parts = _split_blob(piece_mask, crop, params)
            top = int(parts.max())
            if top == 1 and len(by_colour) == 1:
                break
            found += [parts == k for k in range(1, top + 1)]
        if found:
            pieces[int(i)] = (y0, x0, [f for f in found
                                       if cv2.countNonZero(f.view(np.uint8))
                                       >= params.min_area_px])
    lut = np.zeros(n, np.int32)
    boxes: list[tuple[int, int, int, int]] = []
    areas: list[int] = []
    placed: list[tuple[int, int, np.ndarray, int]] = []
    for i in big:
        i = int(i)
        if i not in pieces:
            boxes.append(tuple(int(v) for v in stats[i, :4]))
            areas.append(int(stats[i, cv2.CC_STAT_AREA]))
            lut[i] = len(boxes)
            continue
        y0, x0, found = pieces[i]
        for f in found:
            bx, by, bw, bh = cv2.boundingRect(f.view(np.uint8))
            boxes.append((bx + x0, by + y0, bw, bh))
            areas.append(cv2.countNonZero(f.view(np.uint8)))
            placed.append((y0, x0, f, len(boxes)))
    labels = lut[comp]
    for y0, x0, f, k in placed:
        labels[y0:y0 + f.shape[0], x0:x0 + f.shape[1]][f] = k
    return (labels, np.array(boxes, np.int32).reshape(-1, 4),
            np.array(areas, np.int64))


def _instances_at_scale(foreground: np.ndarray, rgb: np.ndarray, small: np.ndarray,
                        params: SegmentationParams
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Instance separation at the cue scale, labels carried back to the full-resolution mask.

    The blobs are divided on the ``small`` image (4x fewer pixels at half scale; the sizes in
    ``params`` are scaled with it); every full-resolution foreground pixel then takes the
    label of its low-resolution pixel, or of a neighbour on the thin rim that the reduction
    lost. Returns uint16 labels, (N, 4) int32 boxes, (N,) int64 areas at full resolution.
    """
    h, w = small.shape[:2]
    H, W = foreground.shape
    if (h, w) == (H, W):
        labels, boxes, areas = _instances(foreground, rgb, params)
        return labels.astype(np.uint16), boxes, areas
    s = h / H
    small_params = replace(params, min_area_px=max(1, int(round(params.min_area_px * s * s))),
                           split_min_depth_px=params.split_min_depth_px * s,
                           split_min_core_px=max(1, int(round(params.split_min_core_px * s * s))))
    fg_small = cv2.resize(foreground.view(np.uint8) * np.uint8(255), (w, h),
                          interpolation=cv2.INTER_AREA) >= 128
    labels_s, boxes_s, _ = _instances(fg_small, small, small_params)
    labels_s = labels_s.astype(np.uint16)
    n = len(boxes_s)
    if n == 0:
        return np.zeros((H, W), np.uint16), np.zeros((0, 4), np.int32), np.zeros(0, np.int64)
    up = cv2.resize(labels_s, (W, H), interpolation=cv2.INTER_NEAREST)
    labels = np.where(foreground, up, np.uint16(0))
    rim = foreground & (up == 0)
    if rim.any():
        grown = cv2.dilate(up, np.ones((5, 5), np.uint8))
        labels[rim] = grown[rim]
    # Boxes and areas: look only near each low-resolution box.
    boxes = np.zeros((n, 4), np.int32)
    areas = np.zeros(n, np.int64)
    pad = int(np.ceil(1.0 / s)) + 2
    for k, (bx, by, bw, bh) in enumerate(boxes_s, start=1):
        y0, y1 = max(int(by / s) - pad, 0), min(int((by + bh) / s) + pad, H)
        x0, x1 = max(int(bx / s) - pad, 0), min(int((bx + bw) / s) + pad, W)
        m = (labels[y0:y1, x0:x1] == k).view(np.uint8)
        bx, by, bw, bh = cv2.boundingRect(m)
        boxes[k - 1] = (bx + x0, by + y0, bw, bh)
        areas[k - 1] = cv2.countNonZero(m)
    if np.any(areas == 0):
        labels = relabel_sequential(labels)
        keep = areas > 0
        boxes, areas = boxes[keep], areas[keep]
    return labels, boxes, areas


def _colour_pieces(blob: np.ndarray, rgb: np.ndarray, params: SegmentationParams,
                   depth: int = 0) -> list[np.ndarray]:
    """Divide a blob made of parts of different materials by 2-means on shading-invariant
    chroma (a / L, b / L); recursive for three or more materials. Returns bool masks."""
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab)
    ab = lab[blob].astype(np.float32)  # (N, 3)
    L = np.maximum(ab[:, 0], np.float32(40.0))
    feats = (ab[:, 1:] - np.float32(128.0)) * (np.float32(100.0) / L)[:, None]
    min_piece = max(params.min_area_px, int(params.colour_split_min_share * len(feats)))
    if len(feats) < 2 * min_piece:
        return [blob]
    # The test and the clustering use at most ~800 pixels; all pixels then take the nearer
    # centre.
    sample = np.ascontiguousarray(feats[::max(1, len(feats) // 800)])
    if sample.std(axis=0).max() < params.colour_split_delta / 4:
        return [blob]
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 10, 0.5)
    cv2.setRNGSeed(0)
    _, _, centres = cv2.kmeans(sample, 2, None, criteria, 1, cv2.KMEANS_PP_CENTERS)
    if float(np.linalg.norm(centres[0] - centres[1])) < params.colour_split_delta:
        return [blob]
    which = (np.sum((feats - centres[1]) ** 2, axis=1)
             < np.sum((feats - centres[0]) ** 2, axis=1)).astype(np.int32)
    cluster = np.zeros(blob.shape, np.int32)
    cluster[blob] = which.ravel() + 1
    seeds = np.zeros(blob.shape, np.int32)
    n_seeds = 0
    for c in (1, 2):
        m = _open((cluster == c), 1).view(np.uint8)
        n, comp, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        for j in range(1, n):
            if stats[j, cv2.CC_STAT_AREA] >= min_piece:
                n_seeds += 1
                seeds[comp == j] = n_seeds
    if n_seeds < 2:
        return [blob]
    # Every blob pixel joins the nearest seed piece.
    _, nearest = cv2.distanceTransformWithLabels((seeds == 0).astype(np.uint8), cv2.DIST_L2, 3,
                                                 labelType=cv2.DIST_LABEL_PIXEL)
    lut = np.zeros(int(nearest.max()) + 1, np.int32)
    ys, xs = np.nonzero(seeds)
    lut[nearest[ys, xs]] = seeds[ys, xs]
    owner = np.where(blob, lut[nearest], 0)
    pieces = [owner == k for k in range(1, n_seeds + 1)]
    if depth >= 1:
        return pieces
    return [q for p in pieces for q in _colour_pieces(p, rgb, params, depth + 1)]


def _split_blob(blob: np.ndarray, rgb: np.ndarray | None,
                params: SegmentationParams) -> np.ndarray:
    """Labels 1..k of one blob (a crop with a one-pixel border)."""
    dist = cv2.distanceTransform(blob.astype(np.uint8), cv2.DIST_L2, 3)
    top = float(dist.max())
    if top < params.split_min_depth_px:
        return blob.astype(np.int32)
    cores = (dist > params.split_core_fraction * top).astype(np.uint8)
    n, core_labels, stats, _ = cv2.connectedComponentsWithStats(cores, connectivity=8)
    keep = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= params.split_min_core_px]
    if len(keep) < 2:
        return blob.astype(np.int32)
    markers = np.zeros(blob.shape, np.int32)
    markers[~blob] = 1
    for j, k in enumerate(keep):
        markers[core_labels == k] = j + 2
    if rgb is None:
        # Flood the distance map itself: the dividing line runs along the neck.
        relief = cv2.normalize(-dist, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8)
        image = cv2.merge([relief, relief, relief])
    else:
        image = np.ascontiguousarray(cv2.GaussianBlur(rgb, (3, 3), 0))
    markers = _watershed_padded(image, markers)
    out = np.where(blob, markers - 1, 0)
    out[out < 0] = 0
    # Watershed-line pixels inside the blob go to their nearest piece.
    holes = blob & (out == 0)
    if holes.any():
        _, nearest = cv2.distanceTransformWithLabels((out == 0).astype(np.uint8), cv2.DIST_L2,
                                                     3, labelType=cv2.DIST_LABEL_PIXEL)
        ids = np.zeros(int(nearest.max()) + 1, np.int32)
        ys, xs = np.nonzero(out)
        ids[nearest[ys, xs]] = out[ys, xs]
        out[holes] = ids[nearest[holes]]
    return out


def boxes_from_labels(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(x, y, w, h) int32 boxes (N, 4) and int64 areas (N,) of labels 1..N (empty ids: zeros)."""
    from scipy import ndimage

    n = int(labels.max()) if labels.size else 0
    boxes = np.zeros((n, 4), np.int32)
    if n == 0:
        return boxes, np.zeros(0, np.int64)
    areas = pixel_counts(labels, minlength=n + 1)[1:].astype(np.int64)
    for i, sl in enumerate(ndimage.find_objects(labels.astype(np.int32, copy=False), n)):
        if sl is not None:
            boxes[i] = (sl[1].start, sl[0].start, sl[1].stop - sl[1].start,
                        sl[0].stop - sl[0].start)
    return boxes, areas


def relabel_sequential(labels: np.ndarray) -> np.ndarray:
    """Renumber labels to 1..N in order of first appearance id; returns uint16."""
    ids = np.unique(labels)
    ids = ids[ids > 0]
    lut = np.zeros(int(labels.max()) + 1 if labels.size else 1, np.uint16)
    lut[ids] = np.arange(1, ids.size + 1, dtype=np.uint16)
    return lut[labels]


# --------------------------------------------------------------------------- entry point
@dataclass(frozen=True)
class BackgroundModel:
    """An empty-table image prepared once for :func:`segment` (colour spaces at cue scale).

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
    """Convert an (H, W, 3) uint8 RGB empty-table image once, for repeated :func:`segment`."""
    background = _check_rgb(background, 'background')
    small = _downscale(background, params.cue_scale)
    return BackgroundModel(rgb=background, lab=rgb_to_lab(small),
                           hed=rgb_to_hed(small, dark_level=params.hed_dark_level),
                           scale=params.cue_scale)


def _downscale(rgb: np.ndarray, scale: float) -> np.ndarray:
    if scale == 1.0:
        return rgb
    return cv2.resize(rgb, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)


def _upscale(mask: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    if mask.shape == shape[:2]:
        return mask
    return cv2.resize(mask.view(np.uint8), (shape[1], shape[0]),
                      interpolation=cv2.INTER_NEAREST).astype(bool)


def segment(rgb: np.ndarray, *, background: np.ndarray | BackgroundModel | None = None,
            depth_m: np.ndarray | None = None, intrinsics=None,
            T_world_camera: np.ndarray | None = None,
            params: SegmentationParams = SegmentationParams()) -> Segmentation:
    """Segment the parts on a table in one RGB view (paper §3.1), optionally helped by depth.

    The cues are computed at ``params.cue_scale`` (default half resolution); the watershed
    that places the contours and the instance separation run at full resolution.

    Args:
        rgb: (H, W, 3) uint8 RGB image.
        background: optional empty-table image from the same camera, (H, W, 3) uint8 RGB or a
            :class:`BackgroundModel` from :func:`prepare_background` (faster when reused).
            When given, every histogram cut-off is read on the difference to it and the
            'background' cue (LAB distance with shadow test) joins the union.
        depth_m: optional (H, W) float depth in metres aligned to ``rgb`` (0 / NaN invalid).
            With ``intrinsics`` and ``T_world_camera`` it adds the 'depth' cue (not in the
            paper): height above the table plane, see :func:`height_above_table`. It is fused
            with the colour cues: high pixels join the union, pixels with valid depth on the
            table plane veto colour candidates (shadows) and seed the watershed's background;
            pixels without valid depth are left to the colour cues.
        intrinsics: :class:`~tlessbot_ros.core.common.CameraIntrinsics` or a (3, 3) K of
            the image (needed with ``depth_m``).
        T_world_camera: (4, 4) camera pose in the table frame (needed with ``depth_m``).
        params: see :class:`SegmentationParams`.

    Returns:
        :class:`Segmentation` with uint16 labels (0 = background), (N, 4) boxes and timings.
    """
    t_start = time.perf_counter()
    timings: dict[str, float] = {}

    def lap(name: str, t0: float) -> float:
        t1 = time.perf_counter()
        timings[name] = (t1 - t0) * 1e3
        return t1

    rgb = _check_rgb(rgb)
    methods = set(params.methods)
    bgm: BackgroundModel | None = None
    if background is not None:
        bgm = background if isinstance(background, BackgroundModel) else \
            prepare_background(background, params=params)
        if bgm.rgb.shape != rgb.shape:
            raise ValueError(f'background shape {bgm.rgb.shape} differs from image shape '
                             f'{rgb.shape}; it must come from the same camera and resolution')
        if bgm.scale != params.cue_scale:
            bgm = prepare_background(bgm.rgb, params=params)
    use_depth = depth_m is not None and 'depth' in methods
    if depth_m is not None:
        if intrinsics is None or T_world_camera is None:
            raise ValueError('depth_m needs intrinsics= and T_world_camera= (the camera pose '
                             'in the table frame) to find the table plane')
        if np.shape(depth_m) != rgb.shape[:2]:
            raise ValueError(f'depth_m shape {np.shape(depth_m)} differs from the image '
                             f'{rgb.shape[:2]}; align depth to colour first')
    t = t_start
    small = _downscale(rgb, params.cue_scale)
    lab = rgb_to_lab(small)
    t = lap('lab', t)
    bg_lab = None if bgm is None else bgm.lab
    cues: dict[str, np.ndarray] = {}
    candidate = np.zeros(small.shape[:2], bool)
    sure = np.zeros(small.shape[:2], bool)
    # Pixels where colour evidence is not trusted: cast shadows, and table seen by depth.
    shadow = None if bg_lab is None else _shadow(lab, bg_lab, params)
    veto = shadow
    depth_cue = None
    if use_depth:
        K = np.asarray(getattr(intrinsics, 'K', intrinsics))
        height = height_above_table(depth_m, K, T_world_camera,
                                    scale=small.shape[0] / rgb.shape[0])
        if height.shape != small.shape[:2]:
            height = cv2.resize(height, (small.shape[1], small.shape[0]),
                                interpolation=cv2.INTER_NEAREST)
        depth_cue = _depth_cue(height, params)
        veto = depth_cue.table if veto is None else veto | depth_cue.table
        t = lap('depth', t)
    keep = None if veto is None else ~veto
    if 'watershed' in methods:
        if bg_lab is None:
            cand, sure_g = _cutoff_masks(remove_trend(lab[..., 0]), params.grey_floor, params)
        else:
            cand, sure_g = _cutoff_masks(lab[..., 0] - bg_lab[..., 0], params.grey_floor,
                                         params, peak=0.0)
        if keep is not None:
            cand &= keep
            sure_g &= keep
        cues['watershed'] = cand
        candidate |= cand
        sure |= sure_g
    if 'hed' in methods:
        hed = rgb_to_hed(small, dark_level=params.hed_dark_level)
        cand, sure_h = hed_masks(hed, params, reference=None if bgm is None else bgm.hed)
        if keep is not None:
            cand &= keep
            sure_h &= keep
        cues['hed'] = cand
        candidate |= cand
        sure |= sure_h
        t = lap('hed', t)
    if 'lab' in methods:
        cand, sure_l = lab_masks(lab, params, reference=bg_lab)
        if keep is not None:
            cand &= keep
            sure_l &= keep
        cues['lab'] = cand
        candidate |= cand
        sure |= sure_l
    if 'background' in methods and bgm is not None:
        cand = _background_change(lab, bg_lab, params, shadow=shadow)
        if depth_cue is not None:
            cand &= ~depth_cue.table
        cues['background'] = cand
        candidate |= cand
        sure |= _erode(cand, 1)
    if depth_cue is not None:
        cues['depth'] = depth_cue.candidate
        candidate |= depth_cue.candidate
        sure |= depth_cue.sure
    if params.open_px > 0:
        candidate = _open(candidate, params.open_px)
        sure &= candidate
    candidate = _upscale(candidate, rgb.shape)
    sure = _upscale(sure, rgb.shape)
    table = None if depth_cue is None else _upscale(_erode(depth_cue.table, 1), rgb.shape)
    t = lap('cues', t)
    if 'watershed' in methods:
        foreground = watershed_refine(rgb, candidate, _erode(sure, 1), band_px=params.band_px,
                                      sure_background=table)
    else:
        foreground = candidate
    t = lap('watershed', t)
    labels, boxes, areas = _instances_at_scale(foreground, rgb, small, params)
    lap('instances', t)
    timings['total'] = (time.perf_counter() - t_start) * 1e3
    return Segmentation(labels=labels, boxes=boxes, areas=areas, foreground=foreground,
                        cues=cues, timings_ms=timings)


def _background_change(lab: np.ndarray, bg_lab: np.ndarray, params: SegmentationParams, *,
                       shadow: np.ndarray | None = None) -> np.ndarray:
    """LAB distance to the empty table above ``background_delta_e``, shadows excluded."""
    diff = lab - bg_lab
    delta_e_sq = np.einsum('ijk,ijk->ij', diff, diff)
    if shadow is None:
        shadow = _shadow(lab, bg_lab, params)
    return (delta_e_sq > params.background_delta_e ** 2) & ~shadow


def _shadow(lab: np.ndarray, bg_lab: np.ndarray, params: SegmentationParams) -> np.ndarray:
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


def _erode(mask: np.ndarray, radius: int) -> np.ndarray:
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.erode(mask.view(np.uint8), kernel).astype(bool)


def _open(mask: np.ndarray, radius: int) -> np.ndarray:
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    return cv2.morphologyEx(mask.view(np.uint8), cv2.MORPH_OPEN, kernel).astype(bool)
