"""Exact fixed-radius nearest-neighbour queries over a uniform bucket grid (numba).

Scoring a pose asks, for a few hundred scene points, for the nearest model sample closer than a
voxel, and, for the visible model samples, whether a scene point lies within two voxels. A
KD-tree's answer costs mostly call overhead for these small sets; points sorted into cubic
buckets whose edge is at least the search radius answer the same question by scanning the 27
buckets around the query, in one compiled call (docs/bench/code-figures.md). The answers equal
``scipy.spatial.cKDTree.query(..., k=1, distance_upper_bound=r)``: a neighbour counts when its
distance is strictly below ``r``; with none, the distance is inf and the index ``len(points)``
(equidistant neighbours may be resolved differently).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

MAX_BUCKETS = 1 << 21   # the grid's size bound (its start array: 16 MB)


@dataclass(frozen=True)
class PointBuckets:
    """Points sorted into cubic buckets.

    Attributes:
        points: (N, 3) float64 points.
        origin: (3,) lower corner of bucket (0, 0, 0), metres.
        edge_m: bucket edge; queries must use a radius <= edge_m.
        shape: (3,) int64 buckets per axis.
        start: (X*Y*Z + 1,) int64: bucket b holds ``order[start[b]:start[b + 1]]``.
        order: (N,) int64 point indices sorted by bucket.
    """

    points: np.ndarray
    origin: np.ndarray
    edge_m: float
    shape: np.ndarray
    start: np.ndarray
    order: np.ndarray

    @classmethod
    def build(cls, points: np.ndarray, edge_m: float) -> PointBuckets:
        """Buckets of ``edge_m`` (> 0) over the bounding box of (N, 3) points (larger where
        that box would need more than :data:`MAX_BUCKETS`)."""
        if not edge_m > 0:
            raise ValueError(f'bucket edge must be > 0, got {edge_m}')
        points = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
        origin = points.min(axis=0) if len(points) else np.zeros(3)
        extent = points.max(axis=0) - origin if len(points) else np.zeros(3)
        # a cloud metres wide (a real frame's wall or desk taken for a part) in millimetre
        # buckets would need billions: larger buckets answer the same queries, more slowly
        edge_m = float(edge_m)
        while np.prod(np.floor(extent / edge_m) + 1) > MAX_BUCKETS:
            edge_m *= 1.25
        shape = np.floor(extent / edge_m).astype(np.int64) + 1
        cell = np.floor((points - origin) / edge_m).astype(np.int64)
        flat = (cell[:, 0] * shape[1] + cell[:, 1]) * shape[2] + cell[:, 2]
        order = np.argsort(flat, kind='stable')
        start = np.searchsorted(flat[order], np.arange(int(np.prod(shape)) + 1))
        return cls(points, origin.astype(np.float64), float(edge_m), shape, start.astype(np.int64),
                   order.astype(np.int64))

    def nearest(self, queries: np.ndarray, radius_m: float) -> tuple[np.ndarray, np.ndarray]:
        """(dist (Q,), index (Q,)) of the nearest point strictly closer than ``radius_m`` to each
        of the (Q, 3) queries; inf and N where there is none."""
        self._check(radius_m)
        return _nearest_within(np.ascontiguousarray(queries, np.float64).reshape(-1, 3),
                               self.points, self.origin, self.edge_m, self.shape, self.start,
                               self.order, float(radius_m))

    def any_within(self, queries: np.ndarray, radius_m: float) -> np.ndarray:
        """(Q,) bool: some point lies strictly closer than ``radius_m`` to the query (what
        ``np.isfinite(nearest(...)[0])`` says; the scan stops at the first such point)."""
        self._check(radius_m)
        return _any_within(np.ascontiguousarray(queries, np.float64).reshape(-1, 3),
                           self.points, self.origin, self.edge_m, self.shape, self.start,
                           self.order, float(radius_m))

    def _check(self, radius_m: float) -> None:
        if not 0 < radius_m <= self.edge_m:
            raise ValueError(f'radius {radius_m} m must be in (0, bucket edge {self.edge_m} m]')


@njit(cache=True, nogil=True)
def _nearest_within(queries: np.ndarray, points: np.ndarray, origin: np.ndarray, edge: float,
                    shape: np.ndarray, start: np.ndarray, order: np.ndarray,
                    radius: float) -> tuple[np.ndarray, np.ndarray]:
    n_queries = queries.shape[0]
    dist = np.full(n_queries, np.inf)
    index = np.full(n_queries, points.shape[0], np.int64)
    limit = radius * radius
    for q in range(n_queries):
        qx, qy, qz = queries[q, 0], queries[q, 1], queries[q, 2]
        if not (np.isfinite(qx) and np.isfinite(qy) and np.isfinite(qz)):
            continue
        cx = int(np.floor((qx - origin[0]) / edge))
        cy = int(np.floor((qy - origin[1]) / edge))
        cz = int(np.floor((qz - origin[2]) / edge))
        best = limit
        best_index = -1
        for ix in range(max(cx - 1, 0), min(cx + 2, shape[0])):
            for iy in range(max(cy - 1, 0), min(cy + 2, shape[1])):
                for iz in range(max(cz - 1, 0), min(cz + 2, shape[2])):
                    bucket = (ix * shape[1] + iy) * shape[2] + iz
                    for s in range(start[bucket], start[bucket + 1]):
                        j = order[s]
                        dx = points[j, 0] - qx
                        dy = points[j, 1] - qy
                        dz = points[j, 2] - qz
                        d2 = dx * dx + dy * dy + dz * dz
                        if d2 < best or (d2 == best and best_index >= 0 and j < best_index):
                            best = d2
                            best_index = j
        if best_index >= 0:
            dist[q] = np.sqrt(best)
            index[q] = best_index
    return dist, index


@njit(cache=True, nogil=True)
def _any_within(queries: np.ndarray, points: np.ndarray, origin: np.ndarray, edge: float,
                shape: np.ndarray, start: np.ndarray, order: np.ndarray,
                radius: float) -> np.ndarray:
    """(Q,) bool: the test of :func:`_nearest_within` (a squared distance below radius²,
    computed alike) without looking for the nearest."""
    n_queries = queries.shape[0]
    found = np.zeros(n_queries, np.bool_)
    limit = radius * radius
    for q in range(n_queries):
        qx, qy, qz = queries[q, 0], queries[q, 1], queries[q, 2]
        if not (np.isfinite(qx) and np.isfinite(qy) and np.isfinite(qz)):
            continue
        cx = int(np.floor((qx - origin[0]) / edge))
        cy = int(np.floor((qy - origin[1]) / edge))
        cz = int(np.floor((qz - origin[2]) / edge))
        for ix in range(max(cx - 1, 0), min(cx + 2, shape[0])):
            for iy in range(max(cy - 1, 0), min(cy + 2, shape[1])):
                for iz in range(max(cz - 1, 0), min(cz + 2, shape[2])):
                    bucket = (ix * shape[1] + iy) * shape[2] + iz
                    for s in range(start[bucket], start[bucket + 1]):
                        j = order[s]
                        dx = points[j, 0] - qx
                        dy = points[j, 1] - qy
                        dz = points[j, 2] - qz
                        if dx * dx + dy * dy + dz * dz < limit:
                            found[q] = True
                            break
                    if found[q]:
                        break
                if found[q]:
                    break
            if found[q]:
                break
    return found
