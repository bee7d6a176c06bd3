"""An explicit RBF feature map (Nyström) in front of the linear classifiers.

The linear models of the paper (SGD, Perceptron, PA-I, PA-II) stay linear, but they can learn on
``phi(x)`` instead of ``x``: ``phi(x)_j = exp(-gamma * ||P (x - mu) - l_j||^2)`` over M landmarks
``l_j``, where ``P (x - mu)`` standardises the descriptor and projects it on its first principal
axes. With the whitening of the Nyström method [1] (``K_LL^{-1/2}``, folded into the stored
weights), ``phi(x) . phi(y)`` approximates the Gaussian kernel, so a linear model on ``phi``
approximates a kernel SVM, which separates the look-alike classes better than one hyperplane
per class (k = 256 axes, M = 4000 landmarks in the packaged model; its accuracy against the
linear models and an exact SVM: docs/design.md, Recognition; docs/bench/recognition-models.md).

Cost at prediction: a (N, D) @ (D, k) and a (N, k) @ (k, M) product and M exponentials per
crop (D = 1655: ~1.4 M multiply-adds); the time per crop is what ``tlessbot bench recognition``
measures (docs/bench/code-figures.md).

References:
    [1] C. Williams, M. Seeger, "Using the Nyström method to speed up kernel machines",
        NIPS 2001.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import cast

import numpy as np

# Kernel eigenvalues below this share of the largest are dropped from the whitening. The small
# directions carry detail: on 506 held-out crops 1e-6 gave 94.3 %, 1e-4 93.1 %, 1e-3 89.1 %.
EIGEN_CUTOFF = 1e-6


@dataclass(frozen=True)
class RbfFeatureMap:
    """``phi(x) = exp(-gamma ||(x - mean) @ projection - landmarks||^2)`` (unwhitened).

    Attributes:
        mean: (D,) float32 descriptor offset.
        projection: (D, k) float32: standardisation and principal axes in one matrix.
        landmarks: (M, k) float32 landmark points in the projected space.
        gamma: RBF width in the projected space (1 / length^2).
    """

    mean: np.ndarray
    projection: np.ndarray
    landmarks: np.ndarray
    gamma: float
    # set by __post_init__: per-call constants
    _landmarks_t: np.ndarray = field(init=False, repr=False, compare=False)
    _landmark_sq: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        d, k = np.shape(self.projection)
        if np.shape(self.mean) != (d,) or np.ndim(self.landmarks) != 2 \
                or np.shape(self.landmarks)[1] != k:
            raise ValueError(f'inconsistent feature map: mean {np.shape(self.mean)}, projection '
                             f'{np.shape(self.projection)}, landmarks '
                             f'{np.shape(self.landmarks)}; need (D,), (D, k), (M, k)')
        if not self.gamma > 0:
            raise ValueError(f'gamma must be > 0, got {self.gamma}')
        # Per-call constants, computed once: the transposed landmarks (contiguous for the
        # matrix product) and their squared norms.
        landmarks = np.asarray(self.landmarks, np.float32)
        object.__setattr__(self, '_landmarks_t', np.ascontiguousarray(landmarks.T))
        object.__setattr__(self, '_landmark_sq', (landmarks * landmarks).sum(axis=1))

    @property
    def input_dim(self) -> int:
        """D, the descriptor length the map takes."""
        return int(self.projection.shape[0])

    @property
    def output_dim(self) -> int:
        """M, the number of landmarks (the length of ``phi(x)``)."""
        return int(self.landmarks.shape[0])

    def transform(self, features: np.ndarray) -> np.ndarray:
        """(N, D) descriptors -> (N, M) float32 kernel values in (0, 1]."""
        projected = (np.asarray(features, np.float32) - self.mean) @ self.projection
        return _rbf(projected, self._landmarks_t, self._landmark_sq, self.gamma)


def _rbf(points: np.ndarray, landmarks_t: np.ndarray, landmark_sq: np.ndarray,
         gamma: float) -> np.ndarray:
    """(N, k) points, (k, M) landmarks and their (M,) squared norms -> (N, M) float32
    ``exp(-gamma ||p_i - l_j||^2)``."""
    sq = points @ landmarks_t
    sq *= -2.0
    sq += (points * points).sum(axis=1)[:, None]
    sq += landmark_sq
    np.maximum(sq, 0.0, out=sq)
    sq *= -gamma
    return cast(np.ndarray, np.exp(sq, out=sq).astype(np.float32, copy=False))


def _half_precision(values: np.ndarray) -> np.ndarray:
    """float32 values rounded to float16 precision, so that the model file can store them
    as float16 without loss (it halves the file; what it does to the scores:
    docs/bench/code-figures.md)."""
    return np.asarray(values).astype(np.float16).astype(np.float32)


def fit_rbf_map(standardised: np.ndarray, *, mean: np.ndarray, scale: np.ndarray,
                components: int, axes: int, gamma: float, seed: int = 0
                ) -> tuple[RbfFeatureMap, np.ndarray]:
    """Fit a Nyström RBF map on standardised training descriptors.

    Args:
        standardised: (N, D) float32 descriptors already standardised as ``(x - mean) / scale``.
        mean, scale: (D,) the standardisation, folded into the map so it takes raw descriptors.
        components: M landmarks, drawn at random from the training rows (M <= N).
        axes: k principal axes kept (k <= D); the kernel sees the projected descriptors.
        gamma: RBF width relative to the descriptor length D: the map uses ``gamma / D`` (for
            standardised features ``||x - y||^2`` grows like D).
        seed: seeds the choice of landmarks.

    Returns:
        (map, whitening): the map (its projection and landmarks rounded to float16
        precision) and the (M, M) float32 matrix ``K_LL^{-1/2}`` (pseudo-inverse
        square root over eigenvalues above ``EIGEN_CUTOFF`` of the largest) such that
        ``map.transform(x) @ whitening`` are the Nyström features.
    """
    z = np.asarray(standardised, np.float32)
    n, d = z.shape
    if not 1 <= components <= n:
        raise ValueError(f'components must be in 1..{n} (the training rows), got {components}')
    if not 1 <= axes <= d:
        raise ValueError(f'axes must be in 1..{d} (the descriptor length), got {axes}')
    if not gamma > 0:
        raise ValueError(f'gamma must be > 0, got {gamma}')
    centred = z - z.mean(axis=0)
    _, vectors = np.linalg.eigh((centred.T @ centred).astype(np.float64) / n)
    axes_matrix = vectors[:, ::-1][:, :axes]  # largest variance first
    projection = _half_precision(axes_matrix / np.asarray(scale, np.float64)[:, None])
    rng = np.random.default_rng(seed)
    landmarks = _half_precision(z[rng.choice(n, size=components, replace=False)] @ axes_matrix)
    feature_map = RbfFeatureMap(mean=np.asarray(mean, np.float32), projection=projection,
                                landmarks=landmarks, gamma=float(gamma) / d)
    values, vectors = np.linalg.eigh(
        _rbf(landmarks, feature_map._landmarks_t, feature_map._landmark_sq,
             feature_map.gamma).astype(np.float64))
    keep = values > EIGEN_CUTOFF * values.max()
    whitening = (vectors[:, keep] / np.sqrt(values[keep])) @ vectors[:, keep].T
    return feature_map, whitening.astype(np.float32)
