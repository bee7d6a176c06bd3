"""The loop of the table-plane RANSAC (numba), apart so that importing
:mod:`tlessbot_ros.core.common.table_plane` (and the parameters that name its modes) does not
import numba."""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def count_inliers(points, normals, offsets, limits):
    """(H,) number of the (N, 3) points within ``limits`` (N,) of each of the H planes
    (``normals`` (H, 3), ``offsets`` (H,)). One pass, no (N, H) temporaries and no BLAS (whose
    threads spin against the other stages' on a loaded machine: 10+ ms instead of 1)."""
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
def sampled_points(depth_m, stride, cx, cy, fx, fy, max_depth_m):
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
def near_plane(points, normal, offset, limits):
    """(N,) bool: the points within ``limits`` (N,) of the plane (``normal`` (3,), ``offset``)."""
    a, b, c = normal[0], normal[1], normal[2]
    out = np.empty(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        out[i] = abs(points[i, 0] * a + points[i, 1] * b + points[i, 2] * c + offset) < limits[i]
    return out


@njit(cache=True, nogil=True)
def centre_and_scatter(points, chosen):
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
def residuals(points, normal, offset, chosen):
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
def within_noise(points, residual, noise_factor, low, high):
    """(N,) bool: residual below ``noise_factor`` × depth², clipped to [low, high]."""
    out = np.empty(points.shape[0], np.bool_)
    for i in range(points.shape[0]):
        limit = min(max(noise_factor * points[i, 2] ** 2, low), high)
        out[i] = residual[i] < limit
    return out
