"""The statistical outlier removal's loops (numba), with Open3D's arithmetic.

:func:`~tlessbot_ros.core.pose.remove_statistical_outliers` keeps what Open3D's
``PointCloud.remove_statistical_outlier`` keeps (Rusu 2009), without building a KD-tree and
an Open3D cloud for a few hundred points per call. To keep the same points the values must be
the same bits, so every step does Open3D's floating-point operations in its order:

* a squared distance is ``(dx * dx + dy * dy) + dz * dz`` with ``dx = query - point``
  (nanoflann's L2 metric for three coordinates), no fused multiply-add (numba does not fuse
  them unless asked to, and Open3D's wheel is built without);
* a point's mean distance is the sum of the square roots of its ``k`` smallest squared
  distances (itself included, at 0) in ascending order (nanoflann returns them sorted), left
  to right from 0.0, divided by ``k``;
* the cloud's mean skips non-positive means but divides by the number of points, the
  squared deviations are summed in point order, the standard deviation divides by that
  number less one (Bessel), and the threshold is ``mean + ratio * std`` (two roundings);
* a point is kept when its mean distance is > 0 and < the threshold.

Which points tie at the ``k``-th distance does not matter: tied distances are the same
number. The search is exact (:func:`mean_neighbour_distances`); it is fast because a point's
``k``-th distance is close to that of the point before it in Morton order, so the distances
below a guess from it are few more than ``k`` and lie in a slab of the points sorted by x.

Reference: R. B. Rusu, "Semantic 3D Object Maps for Everyday Manipulation in Human Living
Environments", PhD thesis, TU München, 2009.
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, inline='always')
def _spread_bits(v: np.int64) -> np.int64:
    """The low 10 bits of ``v`` spread to every third bit (a Morton code's one axis)."""
    v &= 0x3FF
    v = (v | (v << 16)) & 0x030000FF
    v = (v | (v << 8)) & 0x0300F00F
    v = (v | (v << 4)) & 0x030C30C3
    spread: np.int64 = (v | (v << 2)) & 0x09249249
    return spread


@njit(cache=True, nogil=True)
def _morton_order(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Point indices in Morton (z-curve) order on a 1024³ grid over the bounding cube."""
    n = x.shape[0]
    lo_x, lo_y, lo_z = x.min(), y.min(), z.min()
    extent = max(x.max() - lo_x, y.max() - lo_y, z.max() - lo_z)
    scale = 1023.0 / extent if extent > 0 else 0.0
    code = np.empty(n, np.int64)
    for i in range(n):
        code[i] = (_spread_bits(np.int64((x[i] - lo_x) * scale))
                   | (_spread_bits(np.int64((y[i] - lo_y) * scale)) << 1)
                   | (_spread_bits(np.int64((z[i] - lo_z) * scale)) << 2))
    return np.argsort(code, kind='mergesort')


@njit(cache=True, inline='always')
def _within(px: float, py: float, pz: float, xs: np.ndarray, ys: np.ndarray, zs: np.ndarray,
            bound: float, out: np.ndarray) -> int:
    """Squared distances <= ``bound`` from (px, py, pz) to the x-sorted points whose x lies
    within sqrt(bound) (widened) of px, packed into ``out``; returns their count."""
    first, stop = 0, xs.shape[0]
    if bound < np.inf:
        reach = np.sqrt(bound) * (1.0 + 1e-6) + 1e-12
        first = np.searchsorted(xs, px - reach)
        stop = np.searchsorted(xs, px + reach, side='right')
    count = 0
    for j in range(first, stop):
        dx, dy, dz = px - xs[j], py - ys[j], pz - zs[j]
        d = dx * dx + dy * dy + dz * dz
        out[count] = d
        count += d <= bound
    return count


@njit(cache=True, inline='always')
def _bucket(d: float, scale: float, buckets: int) -> int | np.int64:
    """``floor(d * scale)`` as an index in 0..buckets (an infinite product: the last)."""
    v = d * scale
    return np.int64(v) if v < buckets else buckets


@njit(cache=True, inline='always')
def _smallest_sorted(found: np.ndarray, count: int, m: int, bound: float, starts: np.ndarray,
                     out: np.ndarray) -> int:
    """The ``m`` smallest of the squared distances ``found[:count]`` (all in [0, ``bound``],
    ``count >= m``), ascending, into ``out[:m]``; returns how many of ``out`` it filled (>= m).

    A bucket pass instead of inserting every distance into a sorted list: ``floor(d * scale)``
    never decreases as ``d`` grows (a product by a positive number rounds monotonically), so
    the buckets are in order and only distances that share a bucket can be out of order; an
    insertion sort of the buckets up to the one holding the ``m``-th distance (about one
    distance a bucket) puts them right. ``starts`` is scratch of at least ``count + 1`` ints.
    """
    buckets = count   # about one distance a bucket
    if not bound < np.inf:   # no bound was given: the largest distance
        bound = 0.0
        for a in range(count):
            bound = max(bound, found[a])
    scale = buckets / bound if bound > 0 else 0.0
    if not scale < np.inf:   # a bound so small that the quotient overflows: one bucket
        scale = 0.0
    for b in range(buckets + 1):
        starts[b] = 0
    for a in range(count):
        starts[_bucket(found[a], scale, buckets)] += 1
    # the bucket of the m-th smallest; starts[b] becomes the offset of bucket b in out
    last, total = 0, 0
    for b in range(buckets + 1):
        c = starts[b]
        starts[b] = total
        total += c
        if total >= m:
            last = b
            break
    for a in range(count):
        d = found[a]
        bucket = _bucket(d, scale, buckets)
        if bucket <= last:
            out[starts[bucket]] = d
            starts[bucket] += 1
    for a in range(1, total):
        d = out[a]
        j = a
        while j > 0 and out[j - 1] > d:
            out[j] = out[j - 1]
            j -= 1
        out[j] = d
    return total


@njit(cache=True, nogil=True)
def mean_neighbour_distances(points: np.ndarray, k: int) -> np.ndarray:
    """(N,) float64: for each of the (N, 3) finite float64 points, the mean Euclidean distance
    to its ``min(k, N)`` nearest points, itself included (Open3D's arithmetic, module
    docstring).

    Exact whatever the bound tried first: a point's m = min(k, N) smallest squared distances
    are taken from those <= a bound only when at least m of them are (then no smaller one is
    left out); else from a safe bound, else from all. The bounds are guesses from the previous
    point in Morton order: its m-th distance (a little more), then that plus the step between
    the two points (the triangle inequality).
    """
    n = points.shape[0]
    out = np.empty(n)
    if n == 0:
        return out
    m = min(k, n)
    x = np.ascontiguousarray(points[:, 0])
    y = np.ascontiguousarray(points[:, 1])
    z = np.ascontiguousarray(points[:, 2])
    by_x = np.argsort(x, kind='mergesort')
    xs, ys, zs = x[by_x], y[by_x], z[by_x]
    found = np.empty(n)
    best = np.empty(n)
    starts = np.empty(n + 1, np.int64)
    previous, previous_reach = -1, np.inf
    for i in _morton_order(x, y, z):
        px, py, pz = x[i], y[i], z[i]
        count = 0
        bound = np.inf
        if previous >= 0:
            guess = previous_reach * 1.05
            bound = guess * guess
            count = _within(px, py, pz, xs, ys, zs, bound, found)
            if count < m:
                sx, sy, sz = px - x[previous], py - y[previous], pz - z[previous]
                guess = (previous_reach + np.sqrt(sx * sx + sy * sy + sz * sz)) * 1.000001
                bound = guess * guess
                count = _within(px, py, pz, xs, ys, zs, bound, found)
        if count < m:
            count = _within(px, py, pz, xs, ys, zs, np.inf, found)
            bound = np.inf
        _smallest_sorted(found, count, m, bound, starts, best)
        total = 0.0
        for j in range(m):
            total += np.sqrt(best[j])
        out[i] = total / m
        previous, previous_reach = i, np.sqrt(best[m - 1])
    return out


@njit(cache=True, nogil=True)
def keep_below_threshold(mean_distances: np.ndarray, std_ratio: float) -> np.ndarray:
    """(N,) bool: the points Open3D keeps given their mean neighbour distances (N >= 2)."""
    n = mean_distances.shape[0]
    cloud_mean = 0.0
    for i in range(n):
        if mean_distances[i] > 0:
            cloud_mean += mean_distances[i]
    cloud_mean /= n
    sq_sum = 0.0
    for i in range(n):
        if mean_distances[i] > 0:
            deviation = mean_distances[i] - cloud_mean
            sq_sum += deviation * deviation
    std_dev = np.sqrt(sq_sum / (n - 1))
    threshold = cloud_mean + std_ratio * std_dev
    keep = np.empty(n, np.bool_)
    for i in range(n):
        keep[i] = mean_distances[i] > 0 and mean_distances[i] < threshold
    return keep
