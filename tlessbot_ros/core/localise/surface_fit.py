"""Robust quadratic surface fit of a small image grid (numba), for removing uneven lighting.

:func:`~tlessbot_ros.core.localise.remove_trend` fits z = c0 + c1 x + c2 y + c3 x² + c4 xy + c5 y²
to a subsampled channel by least squares, twice more without the samples beyond 2.5 robust standard
deviations (the parts on the table). It runs six times per view; written with numpy, each pass
spends most of its time in call overhead on a few thousand samples (docs/bench/code-figures.md).
This kernel does the passes in one call, through the 6×6 normal equations (x and y span [-0.5,
0.5], so they are well conditioned; the coefficients equal lstsq's to ~1e-12).
"""
from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def robust_quadratic_fit(sample: np.ndarray, iterations: int) -> np.ndarray:
    """Coefficients (6,) of the robust fit of a (H, W) float64 grid.

    Grid coordinates are x = column / (W - 1) - 0.5 and y = row / (H - 1) - 0.5. Each of the
    ``iterations`` passes fits the kept samples (all at first) and keeps those whose residual
    is below 2.5 × 1.4826 × the median absolute residual of the kept ones; fewer than 12 kept
    samples stop the passes (all-zero coefficients if that happens before the first fit).
    """
    h, w = sample.shape
    n = h * w
    rows = np.empty((n, 6))
    z = np.empty(n)
    for i in range(h):
        y = i / max(h - 1, 1) - 0.5
        for j in range(w):
            x = j / max(w - 1, 1) - 0.5
            k = i * w + j
            rows[k, 0], rows[k, 1], rows[k, 2] = 1.0, x, y
            rows[k, 3], rows[k, 4], rows[k, 5] = x * x, x * y, y * y
            z[k] = sample[i, j]
    keep = np.ones(n, np.bool_)
    coef: np.ndarray = np.zeros(6)
    residual = np.empty(n)
    for _ in range(iterations):
        kept = 0
        normal = np.zeros((6, 6))
        rhs = np.zeros(6)
        for k in range(n):
            if not keep[k]:
                continue
            kept += 1
            for a in range(6):
                rhs[a] += rows[k, a] * z[k]
                for b in range(a, 6):
                    normal[a, b] += rows[k, a] * rows[k, b]
        if kept < 12:
            break
        for a in range(6):
            for b in range(a):
                normal[a, b] = normal[b, a]
        coef = np.linalg.lstsq(normal, rhs)[0]
        kept_abs = np.empty(kept)
        m = 0
        for k in range(n):
            fitted = 0.0
            for a in range(6):
                fitted += rows[k, a] * coef[a]
            residual[k] = z[k] - fitted
            if keep[k]:
                kept_abs[m] = abs(residual[k])
                m += 1
        limit = 2.5 * (1.4826 * np.median(kept_abs) + 1e-9)
        for k in range(n):
            keep[k] = abs(residual[k]) < limit
    return coef
