"""Metric shape features of a part from the aligned depth of its region (our addition to §3.2).

The paper's HOG sees a crop resized to 60×60 px, so the physical size of the part is lost and
23 similar textureless parts are hard to separate linearly (docs/bench/code-figures.md). The
cell knows more: the aligned depth of every crop and the camera's pose on the table (world z = 0
is the table plane, z up). From the region's valid depth pixels, back-projected to the world
frame, this module computes a fixed-length vector of

- heights above the table: percentiles, mean, spread and a histogram in ``hist_bin_m`` bins;
- the footprint on the table plane: PCA extents (length, width, their ratio) and the area of
  the occupied ``area_cell_m`` cells;
- a ``map_cells``×``map_cells`` height map (maximum height per cell) over a fixed
  ``map_size_m`` square window centred on the footprint's median, its x axis along the
  footprint's first principal axis and signs chosen so that the third moments are positive
  (a yaw-normalised, translation-free descriptor).

Lengths are in centimetres so every value is of order 1 before standardisation. Invalid depth
(0 or NaN), flying pixels on the silhouette edge (which land on the table) and outliers are
tolerated: heights below ``min_height_m`` or above ``max_height_m`` are dropped and robust
percentiles are used for extents. With fewer than ``min_points`` valid points the features are
undefined (:func:`shape_features` returns None) and the classifier fills in its training mean.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import cv2
import numpy as np
import numpy.typing as npt

from tlessbot_ros.core.common import mask_box


@dataclass(frozen=True)
class ShapeParams:
    """Shape feature settings (stored in the classifier model file).

    Attributes:
        min_height_m, max_height_m: points outside this height band above the table are ignored
            (table pixels and flying pixels at the silhouette edge, far outliers).
        percentiles: height percentiles in the vector.
        hist_bin_m, hist_bins: height histogram bin width and count (the last bin takes all
            higher points).
        extent_percentiles: (low, high) percentiles that bound the footprint along its axes.
        area_cell_m: grid cell of the footprint area.
        map_cells: height-map side in cells (``map_cells ** 2`` values).
        map_size_m: side of the square height-map window on the table.
        min_points: fewer valid points than this: no shape features.
        rings, ring_m: rotation-invariant radial profile around the footprint centre: per ring
            of width ``ring_m``, the largest height and the share of points.
    """

    min_height_m: float = 0.002
    max_height_m: float = 0.25
    percentiles: tuple[float, ...] = (25.0, 50.0, 75.0, 90.0, 98.0)
    hist_bin_m: float = 0.008
    hist_bins: int = 12
    extent_percentiles: tuple[float, float] = (2.0, 98.0)
    area_cell_m: float = 0.005
    map_cells: int = 16
    map_size_m: float = 0.15
    min_points: int = 10
    rings: int = 8
    ring_m: float = 0.01

    def __post_init__(self) -> None:
        if not 0.0 <= self.min_height_m < self.max_height_m:
            raise ValueError('need 0 <= min_height_m < max_height_m')
        if self.hist_bins < 1 or self.hist_bin_m <= 0:
            raise ValueError('hist_bins must be >= 1 and hist_bin_m > 0')
        if self.map_cells < 1 or self.map_size_m <= 0 or self.area_cell_m <= 0:
            raise ValueError('map_cells must be >= 1, map_size_m and area_cell_m > 0')
        if self.min_points < 3:
            raise ValueError(f'min_points must be >= 3, got {self.min_points}')
        lo, hi = self.extent_percentiles
        if not 0.0 <= lo < hi <= 100.0:
            raise ValueError('extent_percentiles must satisfy 0 <= low < high <= 100')

    @property
    def feature_dim(self) -> int:
        """Length of one shape vector."""
        return (len(self.percentiles) + 2 + self.hist_bins + 4 + self.map_cells ** 2
                + (self.map_cells // 2) ** 2 + 2 * self.rings)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> ShapeParams:
        known = set(cls.__dataclass_fields__)
        values = {k: tuple(v) if isinstance(v, list) else v for k, v in values.items()
                  if k in known}
        return cls(**values)


def region_points_world(depth_m: np.ndarray, mask: np.ndarray, K: np.ndarray,
                        T_world_camera: np.ndarray, *, max_points: int = 400,
                        box: Sequence[float] | None = None) -> np.ndarray:
    """World points of the valid depth pixels of a region.

    Args:
        depth_m: (H, W) z-depth in metres; 0 or NaN = invalid.
        mask: (H, W) bool region (or a box filled True).
        K: (3, 3) camera matrix; any invertible matrix (e.g. after a shear of the image).
        T_world_camera: (4, 4) optical frame -> world (table) frame.
        max_points: keep the region's pixels on an even square grid (every k-th row and
            column of its box) of at most about this many pixels; 0 keeps all. A few hundred
            points keep the shape vector stable at a fraction of the cost of all of them
            (docs/bench/code-figures.md).
        box: optional (x, y, width, height) pixel box that holds the whole mask; only this
            window is read (saves scanning the full frame).

    Returns:
        (N, 3) float32 points in the world frame, metres.
    """
    depth_m = np.asarray(depth_m)
    if depth_m.shape != np.shape(mask):
        raise ValueError(f'depth shape {depth_m.shape} differs from mask shape {np.shape(mask)}')
    height, width = depth_m.shape
    if box is None:
        x0, y0, w, h = mask_box(mask)
    else:
        x0, y0, w, h = (int(round(float(v))) for v in box)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x0 + max(w, 0), width), min(y0 + max(h, 0), height)
    if x1 <= x0 or y1 <= y0:
        return np.zeros((0, 3), np.float32)
    window = np.asarray(mask[y0:y1, x0:x1])
    stride = 1
    if max_points:
        count = cv2.countNonZero(_as_u8(window))
        stride = max(int(np.ceil(np.sqrt(count / max_points))), 1) if count else 1
    window = window[::stride, ::stride]
    z = depth_m[y0:y1:stride, x0:x1:stride]
    keep = (window != 0) & (z > 0)  # NaN compares False
    rows, cols = np.nonzero(keep)
    z = z[rows, cols].astype(np.float64)
    # (int64 columns and rows stacked with float64 ones: float64)
    pix = np.stack([cols * stride + x0, rows * stride + y0, np.ones(len(z))])
    T = np.asarray(T_world_camera, dtype=np.float64)
    K_inv = _inverse(K)
    rays = K_inv @ pix  # z-depth: scale each ray to unit optical z
    points = (T[:3, :3] @ rays) * (z / rays[2]) + T[:3, 3:4]
    return np.ascontiguousarray(points.T, dtype=np.float32)


_INVERSES: dict[bytes, np.ndarray] = {}


def _inverse(K: np.ndarray) -> np.ndarray:
    """``np.linalg.inv`` of a (3, 3) camera matrix, computed once per matrix (a frame's
    regions share their view's)."""
    K = np.asarray(K, dtype=np.float64)
    key = K.tobytes() + bytes(str(K.shape), 'ascii')
    inverse = _INVERSES.get(key)
    if inverse is None:
        inverse = np.linalg.inv(K)
        inverse.setflags(write=False)
        if len(_INVERSES) > 16:
            _INVERSES.clear()
        _INVERSES[key] = inverse
    return inverse


def _as_u8(mask: np.ndarray) -> np.ndarray:
    mask = np.ascontiguousarray(mask)
    return mask.view(np.uint8) if mask.dtype == bool else (mask != 0).astype(np.uint8)


def _sorted_quantiles(values: np.ndarray, percentiles: npt.ArrayLike) -> np.ndarray:
    """np.percentile (linear) of values sorted along axis 0, without re-sorting."""
    position = np.asarray(percentiles, np.float64) / 100.0 * (len(values) - 1)
    low = np.floor(position).astype(np.int64)
    high = np.minimum(low + 1, len(values) - 1)
    frac = (position - low).reshape((-1,) + (1,) * (values.ndim - 1))
    return values[low] * (1.0 - frac) + values[high] * frac


_HALF = 1 << 20  # cell index offset of the area count (21 bits per axis)


def _group_quantiles(values: np.ndarray, group: np.ndarray, start: np.ndarray,
                     count: np.ndarray, percentiles: npt.ArrayLike) -> np.ndarray:
    """(G, P) linear percentiles of ``values`` per group (np.percentile's default rule).

    ``group`` holds the (N,) group of each value; ``start`` and ``count`` (G,) the offset and
    size of each group in group-sorted order (every group non-empty).
    """
    ordered = values[np.lexsort((values, group))]
    position = (np.asarray(percentiles, np.float64)[None] / 100.0) * (count[:, None] - 1)
    low = np.floor(position).astype(np.int64)
    frac = position - low
    high = np.minimum(low + 1, count[:, None] - 1)
    quantiles: np.ndarray = (ordered[start[:, None] + low] * (1.0 - frac)
                             + ordered[start[:, None] + high] * frac)
    return quantiles


def shape_features_batch(points_list: Sequence[np.ndarray], *,
                         params: ShapeParams = ShapeParams()) -> np.ndarray:
    """Metric shape vectors of several regions in one vectorised pass.

    The regions' points are concatenated and every statistic is a grouped numpy operation
    (sorts, ``bincount``, ``maximum.at``), so a frame of crops costs about as many numpy calls
    as one crop.

    Args:
        points_list: B arrays of (N_i, 3) world points (metres, table z = 0), e.g. from
            :func:`region_points_world`; invalid or off-band points are filtered here.
        params: feature settings.

    Returns:
        (B, params.feature_dim) float32; a row is NaN where its region has fewer than
        ``params.min_points`` usable points. Rows equal :func:`shape_features`.
    """
    total = len(points_list)
    out = np.full((total, params.feature_dim), np.nan)
    if total == 0:
        return out.astype(np.float32)
    sizes = [len(p) for p in points_list]
    points = np.concatenate([np.asarray(p, np.float64).reshape(-1, 3) for p in points_list])
    group = np.repeat(np.arange(total), sizes)
    z = points[:, 2]
    keep = ((z > params.min_height_m) & (z < params.max_height_m)
            & np.isfinite(points[:, :2]).all(axis=1))
    count = np.bincount(group[keep], minlength=total)
    ok = count >= params.min_points
    keep &= ok[group]
    if not ok.any():
        return out.astype(np.float32)
    remap = np.cumsum(ok) - 1  # dense ids of the usable regions
    group = remap[group[keep]]
    points = points[keep]
    count = count[ok]
    start = np.concatenate([[0], np.cumsum(count)[:-1]])
    rows = np.empty((len(count), params.feature_dim))
    z_cm = points[:, 2] * 100.0
    k = len(params.percentiles) + 2 + params.hist_bins
    rows[:, :k] = _height_stats(z_cm, group, start, count, params)
    xy, coords, footprint = _footprint(points, group, start, count, params)
    rows[:, k:k + 4] = footprint
    k += 4
    n, half = params.map_cells, params.map_cells // 2
    rows[:, k:k + n * n + half * half] = _height_maps(coords, z_cm, group, len(count), params)
    k += n * n + half * half
    rows[:, k:] = _ring_profile(xy, z_cm, group, count, params)
    out[ok] = rows
    return out.astype(np.float32)


def _height_stats(z_cm: np.ndarray, group: np.ndarray, start: np.ndarray, count: np.ndarray,
                  params: ShapeParams) -> np.ndarray:
    """(G, P + 2 + hist_bins) per region: height percentiles, mean, spread and histogram."""
    k = len(params.percentiles)
    bins = params.hist_bins
    rows = np.empty((len(count), k + 2 + bins))
    rows[:, :k] = _group_quantiles(z_cm, group, start, count, params.percentiles)
    mean = np.bincount(group, z_cm) / count
    rows[:, k] = mean
    rows[:, k + 1] = np.sqrt(np.maximum(np.bincount(group, z_cm * z_cm) / count - mean ** 2,
                                        0.0))
    k += 2
    hist_bin = np.minimum((z_cm / (params.hist_bin_m * 100.0)).astype(np.int64), bins - 1)
    rows[:, k:k + bins] = np.bincount(group * bins + hist_bin, minlength=len(count) * bins
                                      ).reshape(-1, bins) / count[:, None]
    return rows


def _footprint(points: np.ndarray, group: np.ndarray, start: np.ndarray, count: np.ndarray,
               params: ShapeParams) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The footprint on the table: (xy, coords, (G, 4) length, width, ratio, area).

    ``xy`` (N, 2) are the points about their region's median, ``coords`` (N, 2) the same
    along the region's principal axes (yaw-normalised).
    """
    median = np.stack([_group_quantiles(points[:, i], group, start, count, (50.0,))[:, 0]
                       for i in (0, 1)], axis=1)
    xy = points[:, :2] - median[group]
    # Principal axes in closed form (2×2 covariance), signs fixed by the third moments.
    mean_xy = np.stack([np.bincount(group, xy[:, i]) for i in (0, 1)], axis=1) / count[:, None]
    centred = xy - mean_xy[group]
    sxx = np.bincount(group, centred[:, 0] ** 2)
    syy = np.bincount(group, centred[:, 1] ** 2)
    sxy = np.bincount(group, centred[:, 0] * centred[:, 1])
    angle = np.where(count > 2, 0.5 * np.arctan2(2.0 * sxy, sxx - syy), 0.0)
    cos, sin = np.cos(angle)[group], np.sin(angle)[group]
    coords = np.stack([cos * xy[:, 0] + sin * xy[:, 1], -sin * xy[:, 0] + cos * xy[:, 1]],
                      axis=1)
    signs = np.where(np.stack([np.bincount(group, coords[:, i] ** 3) for i in (0, 1)],
                              axis=1) < 0, -1.0, 1.0)
    # Keep a rotation: the minor axis takes the sign of the major one.
    coords *= signs[:, :1][group]
    major, minor = (_group_quantiles(coords[:, i], group, start, count,
                                     params.extent_percentiles) for i in (0, 1))
    length = (major[:, 1] - major[:, 0]) * 100.0
    width = (minor[:, 1] - minor[:, 0]) * 100.0
    # Occupied area: distinct (region, cell) keys; cells are offset to be non-negative.
    cells = np.clip(np.floor(xy / params.area_cell_m).astype(np.int64) + _HALF, 0, 2 * _HALF - 1)
    keys = np.unique((group << 42) | (cells[:, 0] << 21) | cells[:, 1])
    cell_count = np.bincount(keys >> 42, minlength=len(count))
    return xy, coords, np.stack([length, width, width / np.maximum(length, 1e-3),
                                 cell_count * (params.area_cell_m * 100.0) ** 2], axis=1)


def _height_maps(coords: np.ndarray, z_cm: np.ndarray, group: np.ndarray, regions: int,
                 params: ShapeParams) -> np.ndarray:
    """(G, n² + (n // 2)²): the n×n height map (largest height per cell) of each region, then
    the same pooled 2×2."""
    n = params.map_cells
    index = np.floor((coords / params.map_size_m + 0.5) * n).astype(np.int64)
    inside = ((index >= 0) & (index < n)).all(axis=1)
    height_map: np.ndarray = np.zeros(regions * n * n)
    np.maximum.at(height_map, group[inside] * n * n + index[inside, 1] * n + index[inside, 0],
                  z_cm[inside])
    height_map = height_map.reshape(-1, n, n)
    half = n // 2
    pooled = height_map[:, :2 * half, :2 * half].reshape(
        -1, half, 2, half, 2).max(axis=(2, 4)).reshape(-1, half * half)
    return np.hstack([height_map.reshape(-1, n * n), pooled])


def _ring_profile(xy: np.ndarray, z_cm: np.ndarray, group: np.ndarray, count: np.ndarray,
                  params: ShapeParams) -> np.ndarray:
    """(G, 2 * rings): per ring around the footprint centre, the largest height, then the
    share of points."""
    rings = params.rings
    ring = np.minimum((np.hypot(xy[:, 0], xy[:, 1]) / params.ring_m).astype(np.int64),
                      rings - 1)
    ring_max = np.zeros(len(count) * rings)
    np.maximum.at(ring_max, group * rings + ring, z_cm)
    share = np.bincount(group * rings + ring, minlength=len(count) * rings
                        ).reshape(-1, rings) / count[:, None]
    return np.hstack([ring_max.reshape(-1, rings), share])


def shape_features(points_w: np.ndarray, *, params: ShapeParams = ShapeParams()
                   ) -> np.ndarray | None:
    """Metric shape vector of one region (see :func:`shape_features_batch` for several).

    Args:
        points_w: (N, 3) world points of the region (metres, table z = 0), e.g. from
            :func:`region_points_world`; invalid or off-band points are filtered here.
        params: feature settings.

    Returns:
        (params.feature_dim,) float32 vector (lengths in cm, areas in cm², histogram
        fractions), or None when fewer than ``params.min_points`` points are usable.
    """
    row = shape_features_batch([points_w], params=params)[0]
    return None if np.isnan(row[0]) else row
