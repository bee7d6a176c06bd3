"""CAD models of the parts: loading (STL / PLY / OBJ, mm on disk -> m in memory) and resting poses.

Two folder layouts are read:

* a plain folder of ``obj_NN.stl|ply|obj`` files (the T-LESS CAD STLs), and
* a BOP ``models/`` folder with ``obj_0000NN.ply`` and ``models_info.json`` (its symmetries are
  kept; BOP stores them in mm and as flattened 4x4 matrices, see
  https://github.com/thodan/bop_toolkit/blob/master/docs/bop_datasets_format.md).

The object id is the integer in the file name. Duplicate vertices (every STL triangle stores its
own corners) are merged so the mesh is indexed.
"""
from __future__ import annotations

import json
import re
from collections.abc import Callable, Hashable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, TypeVar

import numpy as np

from tlessbot_ros.core.common import point_set_diameter
from tlessbot_ros.errors import ModelFileError

if TYPE_CHECKING:
    from tlessbot_ros.core.common import Symmetries

_T = TypeVar('_T')
MODEL_SUFFIXES = ('.stl', '.ply', '.obj')
_NAME = re.compile(r'^obj_(\d+)$')


@dataclass
class ObjectModel:
    """One rigid part.

    Attributes:
        obj_id: T-LESS / BOP object id (shown as ``obj_05``).
        vertices: (V, 3) float64 vertex positions in metres, model frame.
        faces: (F, 3) int32 vertex indices per triangle.
        normals: (V, 3) float64 unit vertex normals, or None.
        diameter_m: largest distance between two vertices (BOP's object diameter).
        extent_m: (3,) size of the axis-aligned bounding box in metres.
        symmetries_discrete: 4x4 transforms (translation in metres) mapping the model onto
            itself, from ``models_info.json``; empty when none are listed; None when unknown
            (no info file).
        symmetries_continuous: ``{'axis': (3,) array, 'offset_m': (3,) array}`` per continuous
            symmetry axis; same None/empty convention.
        source: the file the mesh came from.
    """

    obj_id: int
    vertices: np.ndarray
    faces: np.ndarray
    diameter_m: float
    extent_m: np.ndarray
    normals: np.ndarray | None = None
    symmetries_discrete: list[np.ndarray] | None = None
    symmetries_continuous: list[dict[str, np.ndarray]] | None = None
    source: Path | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def name(self) -> str:
        return f'obj_{self.obj_id:02d}'

    def cached(self, key: Hashable, build: Callable[[], _T]) -> _T:
        """The value kept on this model under ``key``; ``build()`` makes it on the first call
        (derived data that costs time: stable poses, hulls, ray-casting scenes)."""
        if key not in self._cache:
            self._cache[key] = build()
        return self._cache[key]

    def listed_symmetries(self) -> Symmetries | None:
        """The symmetries ``models_info.json`` lists (the identity added), or None when there
        was no info file: then they are unknown, not absent."""
        from tlessbot_ros.core.common import Symmetries  # Open3D: imported when needed

        if self.symmetries_discrete is None and self.symmetries_continuous is None:
            return None
        return Symmetries(discrete=tuple(self.symmetries_discrete or ()),
                          continuous=tuple((c['axis'], c['offset_m'])
                                           for c in self.symmetries_continuous or ()))


@dataclass
class StablePose:
    """A resting pose on a horizontal plane.

    ``T_table_object`` (4x4, metres) puts the object on the plane z = 0 (lowest point at z = 0,
    centre of mass above the table origin); any yaw about z and shift in x, y is also a resting
    pose.
    ``probability`` is the estimated share of random drops that end in this pose.
    """

    T_table_object: np.ndarray
    probability: float


def object_id_from_path(path: Path) -> int | None:
    """``obj_05.stl`` / ``obj_000005.ply`` -> 5; None for other names."""
    match = _NAME.match(path.stem)
    return int(match.group(1)) if match else None


def _model_files(folder: Path) -> dict[int, Path]:
    files: dict[int, Path] = {}
    for path in sorted(folder.iterdir()):
        if path.suffix.lower() not in MODEL_SUFFIXES:
            continue
        obj_id = object_id_from_path(path)
        if obj_id is None:
            continue
        # Prefer .ply (BOP) over .stl over .obj when one id has several files.
        if obj_id in files:
            rank = {'.ply': 0, '.stl': 1, '.obj': 2}
            if rank[path.suffix.lower()] >= rank[files[obj_id].suffix.lower()]:
                continue
        files[obj_id] = path
    return files


def read_mesh(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices in the file's own units and (F, 3) int32 faces of a mesh file
    (STL / PLY / OBJ), duplicate vertices merged.

    Raises:
        ModelFileError: unreadable, empty or non-finite.
    """
    import open3d as o3d

    try:
        mesh = o3d.io.read_triangle_mesh(str(path))
    except Exception as error:  # Open3D raises RuntimeError on some corrupt files
        raise ModelFileError(f'cannot read model {path}: {error}') from None
    mesh.remove_duplicated_vertices()
    mesh.remove_unreferenced_vertices()
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.triangles, dtype=np.int32)
    if len(vertices) < 4 or len(faces) < 4:
        raise ModelFileError(f'model {path} is empty or unreadable ({len(faces)} triangles)')
    if not np.all(np.isfinite(vertices)):
        raise ModelFileError(f'model {path} has non-finite vertex coordinates')
    return vertices, faces


def diameter(vertices: np.ndarray) -> float:
    """Largest distance between two vertices, metres (BOP's object diameter)."""
    return point_set_diameter(vertices)


def _symmetries(entry: dict) -> tuple[list[np.ndarray], list[dict[str, np.ndarray]]]:
    """The listed symmetries of one ``models_info.json`` entry (metres; identity not listed),
    parsed by :func:`~tlessbot_ros.core.common.symmetries_from_models_info`."""
    from tlessbot_ros.core.common import symmetries_from_models_info  # Open3D: when needed

    symmetries = symmetries_from_models_info(entry)
    return (list(symmetries.discrete[1:]),
            [{'axis': axis, 'offset_m': offset} for axis, offset in symmetries.continuous])


def load_model(path: str | Path, obj_id: int | None = None,
               info: dict | None = None) -> ObjectModel:
    """One model file in millimetres -> :class:`ObjectModel` in metres."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f'model file not found: {path}')
    if obj_id is None:
        obj_id = object_id_from_path(path)
        if obj_id is None:
            raise ModelFileError(f'cannot read an object id from {path.name} (want obj_NN.*)')
    vertices_mm, faces = read_mesh(path)
    vertices = vertices_mm / 1000.0
    discrete = continuous = None
    if info is not None:
        discrete, continuous = _symmetries(info)
    return ObjectModel(obj_id=obj_id, vertices=vertices, faces=faces,
                       diameter_m=diameter(vertices), extent_m=np.ptp(vertices, axis=0),
                       symmetries_discrete=discrete, symmetries_continuous=continuous,
                       source=path)


def load_models(folder: str | Path, ids: list[int] | None = None, *,
                progress: bool = False) -> dict[int, ObjectModel]:
    """All models of a folder (or only ``ids``), keyed by object id, in metres.

    Raises:
        ModelFileError: folder missing, no ``obj_NN.*`` model in it, a requested id missing, or
            an unreadable / empty mesh.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ModelFileError(f'model folder not found: {folder}')
    files = _model_files(folder)
    if not files:
        raise ModelFileError(f'no obj_NN.stl|ply|obj model files in {folder}')
    if ids is not None:
        missing = sorted(set(int(i) for i in ids) - set(files))
        if missing:
            raise ModelFileError(f'{folder} has no model for object id(s) {missing}; '
                                 f'available: {sorted(files)}')
        files = {int(i): files[int(i)] for i in ids}
    infos: dict[str, dict] = {}
    info_path = folder / 'models_info.json'
    if info_path.is_file():
        try:
            infos = json.loads(info_path.read_text(encoding='utf-8'))
        except (OSError, ValueError) as error:
            raise ModelFileError(f'cannot read {info_path}: {error}') from None
    items = sorted(files.items())
    if progress:
        from tqdm import tqdm

        items = tqdm(items, desc='models', unit='model')
    models = {}
    for obj_id, path in items:
        info = infos.get(str(obj_id)) if info_path.is_file() else None
        if info_path.is_file() and info is None:
            info = {}
        models[obj_id] = load_model(path, obj_id, info)
    return models


# --- resting poses ---------------------------------------------------------------------------

def centre_of_mass(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(3,) centre of mass of a closed mesh of uniform density (signed tetrahedra); falls back to
    the centroid of the convex hull's volume if the mesh is not closed enough to give a volume."""
    v = np.asarray(vertices, dtype=np.float64)
    tri = v[np.asarray(faces)]
    vol6 = np.einsum('ij,ij->i', tri[:, 0], np.cross(tri[:, 1], tri[:, 2]))
    total = vol6.sum()
    hull_volume = _hull_volume(v)
    if total != 0 and 0.05 * hull_volume < abs(total) / 6.0 <= 1.01 * hull_volume:
        return (vol6[:, None] * tri.sum(axis=1)).sum(axis=0) / (4.0 * total)
    from scipy.spatial import ConvexHull

    hull = ConvexHull(v)
    tri = hull.points[hull.simplices]
    ref = hull.points[hull.vertices].mean(axis=0)
    rel = tri - ref
    vol6 = np.abs(np.einsum('ij,ij->i', rel[:, 0], np.cross(rel[:, 1], rel[:, 2])))
    return ref + (vol6[:, None] * rel.sum(axis=1)).sum(axis=0) / (4.0 * vol6.sum())


def _hull_volume(v: np.ndarray) -> float:
    from scipy.spatial import ConvexHull

    return float(ConvexHull(v).volume)


def _solid_angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Solid angles (sr) of triangles (N, 3 each) seen from the origin (Van Oosterom-Strackee)."""
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    numer = np.abs(np.einsum('ij,ij->i', a, np.cross(b, c)))
    denom = (la * lb * lc + np.einsum('ij,ij->i', a, b) * lc + np.einsum('ij,ij->i', a, c) * lb
             + np.einsum('ij,ij->i', b, c) * la)
    return 2.0 * np.arctan2(numer, denom)


def _rotation_to_minus_z(n: np.ndarray) -> np.ndarray:
    """Rotation R with R @ n = (0, 0, -1)."""
    target = np.array([0.0, 0.0, -1.0])
    axis = np.cross(n, target)
    s, c = np.linalg.norm(axis), float(np.dot(n, target))
    if s < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    axis /= s
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + s * K + (1 - c) * K @ K


def _facets(hull) -> tuple[np.ndarray, np.ndarray]:
    """Coplanar hull triangles grouped: (facet index per triangle, one triangle per facet)."""
    eq = hull.equations
    scale = max(float(np.ptp(hull.points, axis=0).max()), 1e-9)
    key = np.round(np.c_[eq[:, :3] * 1e4, eq[:, 3] / scale * 1e4]).astype(np.int64)
    _, first, label = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return label.ravel(), first


def stable_poses(model: ObjectModel, *, min_probability: float = 0.0,
                 merge_rolling: bool = False, rolling_angle_deg: float = 10.0
                 ) -> list[StablePose]:
    """Resting poses of ``model`` on a horizontal plane, most probable first.

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

    Results are cached on the model per option set.

    Returns:
        list of :class:`StablePose` with probability >= ``min_probability`` (renormalised to
        sum to 1).
    """
    key = ('stable_poses', float(min_probability), bool(merge_rolling), float(rolling_angle_deg))
    return model.cached(key, lambda: _build_stable_poses(model, min_probability, merge_rolling,
                                                         rolling_angle_deg))


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
    keep = {}
    for f in stable:
        c = component[f]
        if c not in keep or share[f] > share[keep[c]]:
            keep[c] = f
    share = share.copy()
    for c, f in keep.items():
        share[f] = merged[c]
    return share, sorted(keep.values())


def _resting_poses(vertices: np.ndarray, com: np.ndarray, normals: np.ndarray,
                   share: np.ndarray, stable: list[int], min_probability: float
                   ) -> list[StablePose]:
    """StablePoses (4x4 T) of ``stable`` facets >= ``min_probability``, likeliest first."""
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
        poses.append(StablePose(T, float(prob)))
    kept = sum(p.probability for p in poses)
    for pose in poses:
        pose.probability /= kept
    return poses


def _build_stable_poses(model: ObjectModel, min_probability: float, merge_rolling: bool,
                        rolling_angle_deg: float) -> list[StablePose]:
    """The uncached :func:`stable_poses` of ``model``: a list of :class:`StablePose`."""
    com = centre_of_mass(model.vertices, model.faces)
    g = _hull_geometry(model.vertices, com)
    stable_f = _stable_facets(g, model.diameter_m)
    final = _follow_tipping(_tipping_targets(g, stable_f, model.diameter_m))
    n_facets = len(g.normals)
    share = np.bincount(final, weights=g.facet_omega, minlength=n_facets) / (4.0 * np.pi)
    stable = [f for f in range(n_facets) if stable_f[f] and share[f] > 0]
    if merge_rolling and stable:
        share, stable = _merge_rolling(g, com, final, stable_f, share, stable, model.diameter_m,
                                       rolling_angle_deg)
    return _resting_poses(model.vertices, com, g.normals, share, stable, min_probability)
