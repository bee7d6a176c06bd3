"""The loop of the table-plane RANSAC (numba), apart so that importing
:mod:`tlessbot_ros.core.common.table_plane` (and the parameters that name its modes) does not
import numba."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def count_inliers(points: np.ndarray, normals: np.ndarray, offsets: np.ndarray,
                  limits: np.ndarray) -> np.ndarray:
    """(H,) number of the (N, 3) points within ``limits`` (N,) of each of the H planes
    (``normals`` (H, 3), ``offsets`` (H,)). One pass, no (N, H) temporaries and no BLAS, whose
    threads spin against the other stages' on a loaded machine (docs/bench/code-figures.md)."""
    counts = np.zeros(normals.shape[0], np.int64)
    # Coordinates as contiguous columns and a branch-free count: the loop vectorises (4x).
    x = np.ascontiguousarray(points[:, 0])
    y = np.ascontiguousarray(points[:, 1])
    z = np.ascontiguousarray(points[:, 2])
    for h in range(normals.shape[0]):
        a, b, c, d = normals[h, 0], normals[h, 1], normals[h, 2], offsets[h]
        count = 0
        for i in range(x.shape[0]):
            count += abs(a * x[i] + b * y[i] + c * z[i] + d) < limits[i]
        counts[h] = count
    return counts


@njit(cache=True, nogil=True)
def sampled_points(depth_m: np.ndarray, stride: int, cx: float, cy: float, fx: float, fy: float,
                   max_depth_m: float) -> np.ndarray:
    """(N, 3) float64 optical-frame points of every ``stride``-th pixel (from ``stride // 2``)
    whose depth is finite, > 0 and <= ``max_depth_m``, in row-major order; the arithmetic of
    the numpy version it replaced (which scanned the grid five times)."""
    first = stride // 2
    rows = (depth_m.shape[0] - first + stride - 1) // stride
    cols = (depth_m.shape[1] - first + stride - 1) // stride
    out = np.empty((rows * cols, 3))
    n = 0
    for r in range(rows):
        v = r * float(stride) + first
        for c in range(cols):
            z = np.float64(depth_m[first + r * stride, first + c * stride])
            if np.isfinite(z) and z > 0 and z <= max_depth_m:
                u = c * float(stride) + first
                out[n, 0] = (u - cx) * z / fx
                out[n, 1] = (v - cy) * z / fy
                out[n, 2] = z
                n += 1
    return out[:n]


@njit(cache=True, nogil=True)
def near_plane(points: np.ndarray, normal: np.ndarray, offset: float,
               limits: np.ndarray) -> np.ndarray:
    """(N,) bool: the points within ``limits`` (N,) of the plane (``normal`` (3,), ``offset``)."""
    a, b, c = normal[0], normal[1], normal[2]
    out = np.empty(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        out[i] = abs(points[i, 0] * a + points[i, 1] * b + points[i, 2] * c + offset) < limits[i]
    return out


@njit(cache=True, nogil=True)
def centre_and_scatter(points: np.ndarray, chosen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Centroid (3,) of the chosen points and their (3, 3) scatter matrix about it, summed
    point by point in order: equal, bit for bit, to ``points[chosen].mean(axis=0)`` and
    ``np.einsum('ni,nj->ij', centred, centred)``."""
    centre = np.zeros(3)
    count = 0
    for i in range(points.shape[0]):
        if chosen[i]:
            for j in range(3):
                centre[j] += points[i, j]
            count += 1
    centre /= count
    scatter = np.zeros((3, 3))
    d = np.empty(3)
    for i in range(points.shape[0]):
        if chosen[i]:
            for j in range(3):
                d[j] = points[i, j] - centre[j]
            for j in range(3):
                for k in range(3):
                    scatter[j, k] += d[j] * d[k]
    return centre, scatter


@njit(cache=True, nogil=True)
def residuals(points: np.ndarray, normal: np.ndarray, offset: float,
              chosen: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,) absolute distances of all the points to the plane, and (M,) those of the M chosen
    points over their squared depth (the noise measured on the plane, at 1 m)."""
    n = points.shape[0]
    residual = np.empty(n)
    ratio = np.empty(n)
    m = 0
    a, b, c = normal[0], normal[1], normal[2]
    for i in range(n):
        residual[i] = abs(points[i, 0] * a + points[i, 1] * b + points[i, 2] * c + offset)
        if chosen[i]:
            ratio[m] = residual[i] / points[i, 2] ** 2
            m += 1
    return residual, ratio[:m]


@njit(cache=True, nogil=True)
def within_noise(points: np.ndarray, residual: np.ndarray, noise_factor: float, low: float,
                 high: float) -> np.ndarray:
    """(N,) bool: residual below ``noise_factor`` × depth², clipped to [low, high]."""
    out = np.empty(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        limit = min(max(noise_factor * points[i, 2] ** 2, low), high)
        out[i] = residual[i] < limit
    return out


@njit(cache=True, nogil=True)
def triple_normals(triples: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Of (H, 3, 3) point triples, the non-degenerate ones' (H', 3) unit normals (the cross
    product of their edges from the first point), (H', 3) first points and (H',) distances of
    their centres from the origin: the arithmetic of ``np.cross``, ``np.linalg.norm(...,
    axis=1)`` and ``mean(axis=1)`` (sums over x, y, z in order)."""
    count = triples.shape[0]
    normals = np.empty((count, 3))
    firsts = np.empty((count, 3))
    centre_distance = np.empty(count)
    n = 0
    for h in range(count):
        p0x, p0y, p0z = triples[h, 0, 0], triples[h, 0, 1], triples[h, 0, 2]
        ax, ay, az = triples[h, 1, 0] - p0x, triples[h, 1, 1] - p0y, triples[h, 1, 2] - p0z
        bx, by, bz = triples[h, 2, 0] - p0x, triples[h, 2, 1] - p0y, triples[h, 2, 2] - p0z
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        length = np.sqrt(cx * cx + cy * cy + cz * cz)
        if not length > 1e-9:
            continue
        normals[n, 0], normals[n, 1], normals[n, 2] = cx / length, cy / length, cz / length
        firsts[n, 0], firsts[n, 1], firsts[n, 2] = p0x, p0y, p0z
        mx = (triples[h, 0, 0] + triples[h, 1, 0] + triples[h, 2, 0]) / 3.0
        my = (triples[h, 0, 1] + triples[h, 1, 1] + triples[h, 2, 1]) / 3.0
        mz = (triples[h, 0, 2] + triples[h, 1, 2] + triples[h, 2, 2]) / 3.0
        centre_distance[n] = np.sqrt(mx * mx + my * my + mz * mz)
        n += 1
    return normals[:n], firsts[:n], centre_distance[:n]


@njit(cache=True, nogil=True)
def median_in_place(values: np.ndarray) -> float:
    """The median of (N,) values (N > 0, no NaN), as ``np.median`` gives it (the mean of the
    two middle values for even N); reorders ``values``."""
    n = values.shape[0]
    upper = _select_in_place(values, n // 2)
    if n % 2:
        return upper
    lower: float = values[0]
    for i in range(1, n // 2):   # the largest of the lower half
        lower = max(lower, values[i])
    return (lower + upper) / 2.0


@njit(cache=True, nogil=True)
def _select_in_place(values: np.ndarray, k: int) -> float:
    """The k-th smallest (0-based) of ``values``, moved to index k with the smaller ones
    before it (Hoare's quickselect)."""
    lo, hi = 0, values.shape[0] - 1
    while lo < hi:
        pivot = values[(lo + hi) // 2]
        i, j = lo, hi
        while i <= j:
            while values[i] < pivot:
                i += 1
            while values[j] > pivot:
                j -= 1
            if i <= j:
                values[i], values[j] = values[j], values[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            break
    kth: float = values[k]
    return kth
