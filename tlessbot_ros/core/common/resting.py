"""Where a rigid part comes to rest on a horizontal plane: its stable poses and their
probabilities (:func:`resting_poses`, a quasi-static drop model on the convex hull), and the
centre of mass of a closed mesh. The simulator draws parts from these poses
(:func:`tlessbot_ros.io.models.stable_poses`), and the pose stage levels a fit that rests on
the table onto the nearest of them (:mod:`tlessbot_ros.core.pose.resting`): one computation.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


def centre_of_mass(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(3,) centre of mass of a closed mesh of uniform density (signed tetrahedra); falls back to
    the centroid of the convex hull's volume if the mesh is not closed enough to give a volume."""
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces)]
    vol6 = np.einsum('ij,ij->i', tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))
    total = vol6.sum()
    hull_volume = _hull_volume(v)
    if total != 0 and 0.05 * hull_volume < abs(total) / 6.0 <= 1.01 * hull_volume:
        com: np.ndarray = (vol6[:, None] * tri.sum(axis=1)).sum(axis=0) / (4.0 * total)
        return com
    from scipy.spatial import ConvexHull

    hull = ConvexHull(v)
    tri = hull.points[hull.simplices]
    ref = hull.points[hull.vertices].mean(axis=0)
    rel = tri - ref
    vol6 = np.abs(np.einsum('ij,ij->i', rel[:, 0], np.cross(rel[:, 1], rel[:, 2])))
    centroid: np.ndarray = ref + (vol6[:, None] * rel.sum(axis=1)).sum(axis=0) / (
        4.0 * vol6.sum())
    return centroid


def _hull_volume(v: np.ndarray) -> float:
    from scipy.spatial import ConvexHull

    return float(ConvexHull(v).volume)


def _solid_angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Solid angles (sr) of triangles (N, 3 each) seen from the origin (Van Oosterom-Strackee)."""
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    numer = np.abs(np.einsum('ij,ij->i', a, np.cross(b, c)))
    denom = (la * lb * lc + np.einsum('ij,ij->i', a, b) * lc + np.einsum('ij,ij->i', a, c) * lb
             + np.einsum('ij,ij->i', b, c) * la)
    angle: np.ndarray = 2.0 * np.arctan2(numer, denom)
    return angle


def _rotation_to_minus_z(n: np.ndarray) -> np.ndarray:
    """Rotation R with R @ n = (0, 0, -1)."""
    target = np.array([0.0, 0.0, -1.0])
    axis = np.cross(n, target)
    s, c = np.linalg.norm(axis), float(np.dot(n, target))
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    axis /= s
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    R: np.ndarray = np.eye(3) + s * K + (1 - c) * K @ K
    return R


def _facets(hull: Any) -> tuple[np.ndarray, np.ndarray]:
    """Coplanar hull triangles grouped: (facet index per triangle, one triangle per facet)."""
    eq = hull.equations
    scale = max(float(np.ptp(hull.points, axis=0).max()), 1e-9)
    key = np.round(np.c_[eq[:, :3] * 1e4, eq[:, 3] / scale * 1e4]).astype(np.int64)
    _, first, label = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return label.ravel(), first


@dataclass(frozen=True)
class _HullGeometry:
    """The convex hull seen from the centre of mass: F facets, T triangles, 3 edges each."""

    label: np.ndarray        # (T,) facet of each triangle
    normals: np.ndarray      # (F, 3) outward unit facet normals
    offsets: np.ndarray      # (F,) facet planes: normals @ x + offsets = 0
    facet_omega: np.ndarray  # (F,) solid angle (sr) of each facet seen from the centre of mass
    tri_pts: np.ndarray      # (T, 3, 3) triangle corners
    n_t: np.ndarray          # (T, 3) normal of each triangle's facet
    p_t: np.ndarray          # (T, 3) centre of mass projected onto each triangle's plane
    a: np.ndarray            # (T, 3, 3) start of each edge
    ab: np.ndarray           # (T, 3, 3) edge vectors
    ap: np.ndarray           # (T, 3, 3) from each edge's start to p_t
    edge_len: np.ndarray     # (T, 3) edge lengths
    nbr_f: np.ndarray        # (T, 3) facet across each edge
    interior: np.ndarray     # (T, 3) bool: edge between two triangles of the same facet


def _hull_geometry(vertices: np.ndarray, com: np.ndarray) -> _HullGeometry:
    """The :class:`_HullGeometry` of the convex hull of (V, 3) ``vertices`` about (3,) ``com``."""
    from scipy.spatial import ConvexHull

    hull = ConvexHull(vertices)
    label, first_tri = _facets(hull)
    n_facets = len(first_tri)
    points = hull.points
    tri_pts = points[hull.simplices]
    omega = _solid_angle(tri_pts[:, 0] - com, tri_pts[:, 1] - com, tri_pts[:, 2] - com)
    facet_omega = np.bincount(label, weights=omega, minlength=n_facets)
    normals = hull.equations[first_tri, :3]
    offsets = hull.equations[first_tri, 3]
    # Centre of mass projected onto each triangle's (= its facet's) plane.
    n_t = normals[label]
    p_t = com - (n_t @ com + offsets[label])[:, None] * n_t
    # Edge i of a triangle is opposite vertex i; hull.neighbors[t, i] shares that edge.
    a = tri_pts[:, [1, 2, 0]]
    b = tri_pts[:, [2, 0, 1]]
    ab = b - a
    ap = p_t[:, None, :] - a
    edge_len = np.linalg.norm(ab, axis=2)
    nbr_f = label[hull.neighbors]
    interior = nbr_f == label[:, None]  # edges between two triangles of the same facet
    return _HullGeometry(label, normals, offsets, facet_omega, tri_pts, n_t, p_t, a, ab, ap,
                         edge_len, nbr_f, interior)


def _stable_facets(g: _HullGeometry, diameter_m: float) -> np.ndarray:
    """(F,) bool: the centre of mass projects inside the facet (a stable resting face)."""
    # qhull does not orient its simplices: measure sides relative to each triangle's winding.
    tri_pts, n_t = g.tri_pts, g.n_t
    winding = np.sign(np.einsum('tj,tj->t', np.cross(tri_pts[:, 1] - tri_pts[:, 0],
                                                     tri_pts[:, 2] - tri_pts[:, 0]), n_t))
    side = np.einsum('tij,tj->ti', np.cross(g.ab, g.ap), n_t) * winding[:, None]
    margin = np.where(g.interior, -1e-6, 1e-6) * diameter_m * g.edge_len
    inside_t = np.all(side >= margin, axis=1)
    return np.bincount(g.label, weights=inside_t, minlength=len(g.normals)) > 0


def _tipping_targets(g: _HullGeometry, stable_f: np.ndarray, diameter_m: float) -> np.ndarray:
    """(F,) int: the facet each facet tips onto (a stable facet: itself)."""
    n_facets = len(g.normals)
    label, p_t, a, ab, ap, edge_len = g.label, g.p_t, g.a, g.ab, g.ap, g.edge_len
    # Unstable facet: it tips over the boundary edge nearest to the projected centre of mass
    # onto the neighbouring facet across it (ties at a corner: the neighbour whose normal leans
    # most toward the centre of mass).
    t = np.clip(np.einsum('tij,tij->ti', ap, ab) / np.maximum(edge_len ** 2, 1e-30), 0.0, 1.0)
    q = a + t[..., None] * ab
    dist = np.linalg.norm(p_t[:, None, :] - q, axis=2)
    dist[g.interior] = np.inf
    facet_of_edge = np.repeat(label, 3)
    nearest = np.full(n_facets, np.inf)
    np.minimum.at(nearest, facet_of_edge, dist.ravel())
    cand = dist.ravel() <= nearest[facet_of_edge] + 1e-9 * diameter_m
    cand &= ~stable_f[facet_of_edge]
    tip = (p_t[:, None, :] - q).reshape(-1, 3)[cand]
    tip /= np.maximum(np.linalg.norm(tip, axis=1, keepdims=True), 1e-30)
    c_facet = facet_of_edge[cand]
    c_next = g.nbr_f.ravel()[cand]
    score = np.sum(g.normals[c_next] * tip, axis=1)
    order = np.lexsort((-score, c_facet))
    first = np.unique(c_facet[order], return_index=True)[1]
    next_facet = np.arange(n_facets)
    next_facet[c_facet[order][first]] = c_next[order][first]
    return next_facet


def _follow_tipping(next_facet: np.ndarray) -> np.ndarray:
    """(F,) int: the facet each facet's tipping chain ends on, from (F,) ``next_facet``."""
    # Follow the tipping chains (the centre of mass drops at each step, so they end).
    n_facets = len(next_facet)
    final = np.arange(n_facets)
    for f in range(n_facets):
        seen, cur = set(), f
        while next_facet[cur] != cur and cur not in seen:
            seen.add(cur)
            cur = next_facet[cur]
        final[f] = cur
    return final


def _merge_rolling(g: _HullGeometry, com: np.ndarray, final: np.ndarray, stable_f: np.ndarray,
                   share: np.ndarray, stable: list[int], diameter_m: float,
                   rolling_angle_deg: float) -> tuple[np.ndarray, list[int]]:
    """((F,) shares, sorted resting facets): each rolling group kept as its likeliest facet."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    n_facets, normals = len(g.normals), g.normals
    fa, fb = np.repeat(g.label, 3), g.nbr_f.ravel()
    close = np.einsum('ij,ij->i', normals[fa], normals[fb]) > np.cos(
        np.radians(rolling_angle_deg))
    # Adjacent, nearly parallel facets roll into each other: join where they come to rest.
    # Rolling keeps the centre of mass at one height; faces joined by a fillet do not.
    height = -(normals @ com + g.offsets)
    ra, rb = final[fa], final[fb]
    level = np.abs(height[ra] - height[rb]) < max(5e-4, 0.01 * diameter_m)
    link = (ra != rb) & close & level & stable_f[ra] & stable_f[rb]
    graph = coo_matrix((np.ones(int(link.sum())), (ra[link], rb[link])),
                       shape=(n_facets, n_facets))
    _, component = connected_components(graph, directed=False)
    merged = np.bincount(component, weights=np.where(stable_f, share, 0.0))
    keep: dict[int, int] = {}
    for f in stable:
        c = int(component[f])
        if c not in keep or share[f] > share[keep[c]]:
            keep[c] = f
    share = share.copy()
    for c, f in keep.items():
        share[f] = merged[c]
    return share, sorted(keep.values())


def _resting_poses(vertices: np.ndarray, com: np.ndarray, normals: np.ndarray,
                   share: np.ndarray, stable: list[int], min_probability: float
                   ) -> list[tuple[np.ndarray, float]]:
    """(4x4 T, probability) of ``stable`` facets >= ``min_probability``, likeliest first."""
    total = sum(share[f] for f in stable)
    poses = []
    for f in sorted(stable, key=lambda f: -share[f]):
        prob = share[f] / total
        if prob < min_probability:
            continue
        R = _rotation_to_minus_z(normals[f])
        moved = vertices @ R.T
        c = R @ com
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = [-c[0], -c[1], -moved[:, 2].min()]
        poses.append((T, float(prob)))
    kept = sum(p for _, p in poses)
    return [(T, p / kept) for T, p in poses]


def resting_poses(vertices: np.ndarray, faces: np.ndarray, diameter_m: float, *,
                  min_probability: float = 0.0, merge_rolling: bool = False,
                  rolling_angle_deg: float = 10.0) -> list[tuple[np.ndarray, float]]:
    """Resting poses of a closed mesh ((V, 3) ``vertices`` m, (F, 3) ``faces``; ``diameter_m``
    its diameter) on a horizontal plane, most probable first: ``(T_table_object, probability)``
    pairs; ``T_table_object`` (4x4) puts the lowest point on z = 0 and the centre of mass above
    the origin (any yaw and shift on the plane rests too); the probabilities >=
    ``min_probability``, renormalised to sum to 1.

    Quasi-static drop model: the part rests on a face of its convex hull; a face is stable when
    the centre of mass projects inside it. Every hull face is reached with a probability equal
    to its solid angle seen from the centre of mass (a random orientation of the gravity vector);
    an unstable face tips over the edge nearest to the projected centre of mass onto the
    neighbouring face, until a stable face is reached, and passes its share on. Curved parts get
    one pose per hull facet of their rolling surface (each with a small probability); with
    ``merge_rolling`` the resting facets reached from adjacent hull facets whose normals differ
    by less than ``rolling_angle_deg``, at the same height of the centre of mass (within
    max(0.5 mm, 1 % of the diameter): neutral equilibrium), count as one pose (lying on the
    curved side), represented by its most probable facet and carrying the summed probability.
    """
    vertices = np.asarray(vertices, np.float64)
    com = centre_of_mass(vertices, faces)
    g = _hull_geometry(vertices, com)
    stable_f = _stable_facets(g, diameter_m)
    final = _follow_tipping(_tipping_targets(g, stable_f, diameter_m))
    n_facets = len(g.normals)
    share = np.bincount(final, weights=g.facet_omega, minlength=n_facets) / (4.0 * np.pi)
    stable = [f for f in range(n_facets) if stable_f[f] and share[f] > 0]
    if merge_rolling and stable:
        share, stable = _merge_rolling(g, com, final, stable_f, share, stable, diameter_m,
                                       rolling_angle_deg)
    return _resting_poses(vertices, com, g.normals, share, stable, min_probability)


__all__ = ['centre_of_mass', 'resting_poses']
