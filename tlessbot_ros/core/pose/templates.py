"""Template database for pose estimation (paper §3.3, §6.2: 12 turntable views, 30° apart).

Each object gets N partial views (2–18, default 12) rendered from its CAD model as the side camera
sees it resting on the table in a stable pose, the table turned in yaw steps of 360°/N, or views
captured from real turntable clouds (:func:`template_from_cloud`). A template stores its
voxelised cloud and the pose of the object in the template's camera frame; its normals (facing
the camera) and FPFH features (Rusu 2009) are computed on first use by the RANSAC path and kept in
memory, never stored (format version 2: FPFH was 90 % of a version-1 file). Per object the
database also keeps what the fast table-plane path of
:mod:`tlessbot_ros.core.pose.estimator` needs: surface samples with normals, the stable poses
on the table, and the yaw period of each stable pose (its
rotational symmetry about the table normal, detected from the mesh: 2π for none, π for a 180°
flip, ~0 for a continuous axis).

Files are ``.npz`` loaded with ``allow_pickle=False``; units are metres.

References:
    R. B. Rusu, N. Blodow, M. Beetz, "Fast Point Feature Histograms (FPFH) for 3D
    Registration", ICRA 2009.
"""
from __future__ import annotations

import json
import zipfile
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import open3d as o3d
from scipy.spatial import cKDTree

from tlessbot_ros.core.common import (
    CameraIntrinsics,
    depth_to_points,
    invert_transform,
    make_transform,
    point_set_diameter,
    raycasting_scene,
    rotation_about_axis,
    transform_points,
)
from tlessbot_ros.core.pose.buckets import PointBuckets
from tlessbot_ros.core.pose.cloud import CloudParams, estimate_normals, preprocess_roi, to_o3d
from tlessbot_ros.core.pose.lookalike import LookalikeCheck, lookalike_pairs
from tlessbot_ros.errors import ModelFileError

FORMAT = 'tlessbot_templates'
VERSION = 3
# Version 2 files (no look-alike meshes) still load; their parts are never checked as
# look-alikes.
READABLE_VERSIONS = (2, 3)
MIN_VIEWS, MAX_VIEWS = 2, 18
CONTINUOUS_YAW_PERIOD = 0.0
# Storage: points as int16 multiples of 0.05 mm (10x below the sensor noise), unit normals as
# int8 / 127; this, and no stored FPFH, keeps all 23 T-LESS objects near 1 MB.
POINT_QUANTUM_M = 5e-5
NORMAL_SCALE = 127.0


@dataclass(frozen=True)
class TemplateParams:
    """Template-building parameters.

    Attributes:
        n_views: turntable views per stable pose (paper: 12, 30° apart; 2–18 allowed).
        voxel_fraction: voxel edge as a fraction of the object diameter (algo-notes §C.3:
            diam/20–diam/30).
        fpfh_radius_voxels, fpfh_max_nn: FPFH support (algo-notes §C.3: 5 voxels, 100).
        max_stable_poses: templates are rendered for the most probable stable poses, up to this
            many (the paper's turntable shows the part in one pose).
        min_stable_probability: stable poses less likely than this are ignored.
        model_samples: surface samples per object for the fast path and ICP.
        seed: seed of the surface sampling.
        lookalike_min_shared, lookalike_tolerance_m: parts sharing at least this share of
            their surface within this distance are look-alikes
            (:func:`~tlessbot_ros.core.pose.lookalike_pairs`); their meshes are stored so
            the pose stage can tell them apart.
    """

    n_views: int = 12
    voxel_fraction: float = 1.0 / 25.0
    fpfh_radius_voxels: float = 5.0
    fpfh_max_nn: int = 100
    max_stable_poses: int = 1
    min_stable_probability: float = 0.02
    model_samples: int = 3000
    seed: int = 0
    lookalike_min_shared: float = 0.8
    lookalike_tolerance_m: float = 0.002
    cloud: CloudParams = field(default_factory=CloudParams)

    def __post_init__(self) -> None:
        if not MIN_VIEWS <= self.n_views <= MAX_VIEWS:
            raise ValueError(f'n_views must be in [{MIN_VIEWS}, {MAX_VIEWS}], got {self.n_views}')
        if not 0.0 < self.voxel_fraction < 0.5:
            raise ValueError(f'voxel_fraction must be in (0, 0.5), got {self.voxel_fraction}')
        if self.max_stable_poses < 1 or self.model_samples < 100:
            raise ValueError('max_stable_poses must be >= 1 and model_samples >= 100')


@dataclass
class Template:
    """One partial view of an object.

    Attributes:
        points: (N, 3) float32 voxelised view cloud in the template camera frame, metres.
        normals: (N, 3) float32 unit normals facing the camera, or None until
            :meth:`ObjectTemplates.features` computes them.
        fpfh: (N, 33) float32 FPFH descriptors, or None (computed lazily likewise).
        T_camera_object: (4, 4) float64 pose of the object in the template camera frame.
        stable_index: index of the stable pose the object rests in (-1: unknown / captured).
        yaw_rad: turntable yaw of the view.
    """

    points: np.ndarray
    normals: np.ndarray | None
    fpfh: np.ndarray | None
    T_camera_object: np.ndarray
    stable_index: int = -1
    yaw_rad: float = 0.0


@dataclass
class ObjectTemplates:
    """Everything the pose estimator knows about one object.

    Attributes:
        obj_id: T-LESS object id.
        diameter_m: object diameter (largest vertex distance), metres.
        voxel_size_m: voxel edge the templates were made with.
        model_points, model_normals: (M, 3) float32 surface samples and unit outward normals in
            the object frame.
        stable_poses: (S, 4, 4) float64 ``T_table_object`` of the stable poses (object resting
            on z = 0 of the table frame), most probable first.
        stable_probabilities: (S,) float64.
        yaw_periods: (S,) float64 yaw symmetry period of each stable pose about the table normal
            through the object origin, radians (2π: none; 0: continuous).
        templates: the views.
        normal_radius_voxels, normal_max_nn, fpfh_radius_voxels, fpfh_max_nn: the feature
            settings of :meth:`features` (as when the templates were made).
        lookalikes: ids of the parts that look like this one (see
            :mod:`tlessbot_ros.core.pose.lookalike`); empty for most.
        mesh_vertices, mesh_faces: (V, 3) float32 metres and (F, 3) int32, the CAD mesh, kept
            only for parts with look-alikes (None otherwise).
    """

    obj_id: int
    diameter_m: float
    voxel_size_m: float
    model_points: np.ndarray
    model_normals: np.ndarray
    stable_poses: np.ndarray
    stable_probabilities: np.ndarray
    yaw_periods: np.ndarray
    templates: list[Template] = field(default_factory=list)
    normal_radius_voxels: float = 2.0
    normal_max_nn: int = 30
    fpfh_radius_voxels: float = 5.0
    fpfh_max_nn: int = 100
    lookalikes: tuple[int, ...] = ()
    mesh_vertices: np.ndarray | None = None
    mesh_faces: np.ndarray | None = None
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def features(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Normals (N, 3) and FPFH (N, 33) float32 of template ``index``, computed on the first
        call (~5-15 ms per template) and kept on the template."""
        template = self.templates[index]
        voxel = self.voxel_size_m
        if template.normals is None:
            template.normals = estimate_normals(
                template.points, radius_m=self.normal_radius_voxels * voxel,
                max_nn=self.normal_max_nn).astype(np.float32)
        if template.fpfh is None:
            template.fpfh = compute_fpfh(template.points, template.normals,
                                         radius_m=self.fpfh_radius_voxels * voxel,
                                         max_nn=self.fpfh_max_nn)
        return template.normals, template.fpfh

    def model_tree(self) -> cKDTree:
        """KD-tree of ``model_points`` (built once)."""
        if 'tree' not in self._cache:
            self._cache['tree'] = cKDTree(self.model_points.astype(np.float64))
        return self._cache['tree']

    def model_buckets(self, edge_m: float) -> PointBuckets:
        """``model_points`` in buckets of ``edge_m`` (built once per edge) for exact
        fixed-radius nearest-sample queries up to that radius."""
        key = ('buckets', round(float(edge_m), 9))
        if key not in self._cache:
            self._cache[key] = PointBuckets.build(self.model_points, edge_m)
        return self._cache[key]

    def nearest_grid(self, spacing_m: float | None = None) -> NearestGrid:
        """A voxel grid of the nearest model sample of every cell (built once per spacing)."""
        spacing = float(spacing_m or self.voxel_size_m / 2.0)
        key = ('grid', round(spacing, 6))
        if key not in self._cache:
            self._cache[key] = NearestGrid.build(self.model_points, spacing,
                                                 margin_m=4.0 * self.voxel_size_m,
                                                 tree=self.model_tree())
        return self._cache[key]


@dataclass
class NearestGrid:
    """Dense lookup of the nearest model sample: ``index[cell]`` and ``distance[cell]``.

    Attributes:
        origin: (3,) float64 lower corner (cell centres at origin + (i + 0.5) * spacing).
        spacing: cell edge in metres.
        index: (X, Y, Z) int32 nearest sample of each cell centre.
        distance: (X, Y, Z) float32 distance from the cell centre to that sample.
    """

    origin: np.ndarray
    spacing: float
    index: np.ndarray
    distance: np.ndarray

    @classmethod
    def build(cls, points: np.ndarray, spacing: float, *, margin_m: float,
              tree: cKDTree | None = None) -> NearestGrid:
        lo = points.min(axis=0) - margin_m
        hi = points.max(axis=0) + margin_m
        shape = np.maximum(np.ceil((hi - lo) / spacing).astype(int), 1)
        axes = [lo[i] + (np.arange(shape[i]) + 0.5) * spacing for i in range(3)]
        centres = np.stack(np.meshgrid(*axes, indexing='ij'), axis=-1).reshape(-1, 3)
        tree = tree or cKDTree(points)
        distance, index = tree.query(centres, k=1)
        return cls(lo, float(spacing), index.reshape(shape).astype(np.int32),
                   distance.reshape(shape).astype(np.float32))

    def lookup(self, points: np.ndarray, *, outside: float = np.inf) -> tuple[np.ndarray,
                                                                               np.ndarray]:
        """Nearest-cell lookup of (..., 3) points: (index, distance); outside the grid the
        index is -1 and the distance ``outside``."""
        cell = np.floor((points - self.origin) / self.spacing).astype(np.int64)
        shape = np.array(self.index.shape)
        inside = np.all((cell >= 0) & (cell < shape), axis=-1)
        cell = np.clip(cell, 0, shape - 1)
        flat = (cell[..., 0] * shape[1] + cell[..., 1]) * shape[2] + cell[..., 2]
        index = np.where(inside, self.index.ravel()[flat], -1)
        distance = np.where(inside, self.distance.ravel()[flat], outside)
        return index, distance


@dataclass
class TemplateDatabase:
    """Templates of several objects, keyed by T-LESS id; save/load as ``.npz``."""

    objects: dict[int, ObjectTemplates] = field(default_factory=dict)
    params: dict = field(default_factory=dict)

    def __getitem__(self, obj_id: int) -> ObjectTemplates:
        try:
            return self.objects[int(obj_id)]
        except KeyError:
            raise KeyError(f'no templates for obj_{int(obj_id):02d}; the database has '
                           f'{sorted(self.objects)}') from None

    def precompute_features(self, ids: Iterable[int] | None = None) -> None:
        """Compute every template's normals and FPFH now (about 5-15 ms per template) instead of
        on first use, so the first RANSAC fallback of an object is not slower than later ones."""
        for obj_id in (self.objects if ids is None else ids):
            obj = self[obj_id]
            for index in range(len(obj.templates)):
                obj.features(index)

    def __contains__(self, obj_id: object) -> bool:
        return obj_id in self.objects

    def lookalike_check(self, *, tolerance_m: float = 0.002) -> LookalikeCheck:
        """A :class:`~tlessbot_ros.core.pose.LookalikeCheck` over the stored look-alikes
        (it checks nothing for a database without any)."""
        objects = [o for o in self.objects.values() if o.lookalikes and o.mesh_faces is not None]
        return LookalikeCheck({o.obj_id: (o.mesh_vertices, o.mesh_faces) for o in objects},
                              {o.obj_id: o.lookalikes for o in objects}, tolerance_m=tolerance_m)

    def save(self, path: str | Path) -> None:
        """Write the database as a compressed ``.npz`` (no pickled objects; template normals and
        FPFH are not stored, see :meth:`ObjectTemplates.features`)."""
        arrays: dict[str, np.ndarray] = {
            'format': np.array(FORMAT), 'version': np.array(VERSION),
            'params_json': np.array(json.dumps(self.params)),
            'obj_ids': np.array(sorted(self.objects), dtype=np.int64)}
        for obj_id, obj in self.objects.items():
            p = f'o{obj_id}_'
            arrays[p + 'scalars'] = np.array([obj.diameter_m, obj.voxel_size_m,
                                              obj.normal_radius_voxels, obj.normal_max_nn,
                                              obj.fpfh_radius_voxels, obj.fpfh_max_nn],
                                             np.float64)
            arrays[p + 'model_points'] = _quantise(obj.model_points, np.zeros(3))
            arrays[p + 'model_normals'] = np.round(
                np.clip(obj.model_normals, -1.0, 1.0) * NORMAL_SCALE).astype(np.int8)
            arrays[p + 'stable_poses'] = np.asarray(obj.stable_poses, np.float64).reshape(-1, 4, 4)
            arrays[p + 'stable_probabilities'] = np.asarray(obj.stable_probabilities, np.float64)
            arrays[p + 'yaw_periods'] = np.asarray(obj.yaw_periods, np.float64)
            t = obj.templates
            counts = [len(x.points) for x in t]
            arrays[p + 'offsets'] = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
            origins = np.array([x.points.mean(axis=0) if len(x.points) else np.zeros(3)
                                for x in t], np.float64).reshape(-1, 3)
            arrays[p + 'origins'] = origins
            arrays[p + 'points'] = np.concatenate(
                [_quantise(x.points, o) for x, o in zip(t, origins)]
                or [np.zeros((0, 3), np.int16)])
            arrays[p + 'T_camera_object'] = np.array(
                [x.T_camera_object for x in t], np.float64).reshape(-1, 4, 4)
            arrays[p + 'stable_index'] = np.array([x.stable_index for x in t], np.int64)
            arrays[p + 'yaw_rad'] = np.array([x.yaw_rad for x in t], np.float64)
            arrays[p + 'lookalikes'] = np.array(obj.lookalikes, np.int64)
            if obj.mesh_vertices is not None and obj.mesh_faces is not None:
                arrays[p + 'mesh_vertices'] = _quantise(obj.mesh_vertices, np.zeros(3))
                arrays[p + 'mesh_faces'] = np.asarray(obj.mesh_faces, np.int32)
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, 'wb') as stream:
            np.savez_compressed(stream, **arrays)

    @classmethod
    def load(cls, path: str | Path) -> TemplateDatabase:
        """Read a database written by :meth:`save`; ``ModelFileError`` if missing or corrupt."""
        path = Path(path)
        if not path.is_file():
            raise ModelFileError(f'template database not found: {path}')
        try:
            with np.load(path, allow_pickle=False) as data:
                if 'format' not in data.files or str(data['format']) != FORMAT:
                    raise ModelFileError(f'{path} is not a tlessbot template database')
                if int(data['version']) not in READABLE_VERSIONS:
                    raise ModelFileError(f'{path}: template format version '
                                         f'{int(data["version"])}, expected one of '
                                         f'{READABLE_VERSIONS}; rebuild it with '
                                         '`tlessbot templates`')
                db = cls(params=json.loads(str(data['params_json'])))
                for obj_id in data['obj_ids'].tolist():
                    db.objects[int(obj_id)] = _read_object(data, int(obj_id))
        except ModelFileError:
            raise
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as error:
            raise ModelFileError(f'corrupt template database {path}: {error}') from None
        return db


def _quantise(points: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """(N, 3) metres -> int16 multiples of ``POINT_QUANTUM_M`` relative to ``origin``."""
    q = np.round((np.asarray(points, np.float64) - origin) / POINT_QUANTUM_M)
    if len(q) and np.abs(q).max() > np.iinfo(np.int16).max:
        raise ValueError('points lie more than 1.6 m from their origin; cannot store them')
    return q.astype(np.int16)


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-9)


def _read_object(data: np.lib.npyio.NpzFile, obj_id: int) -> ObjectTemplates:
    p = f'o{obj_id}_'
    scalars = data[p + 'scalars']
    offsets = data[p + 'offsets']
    origins = data[p + 'origins']
    counts = np.diff(offsets)
    points = (data[p + 'points'].astype(np.float64) * POINT_QUANTUM_M +
              np.repeat(origins, counts, axis=0)).astype(np.float32)
    poses = data[p + 'T_camera_object']
    stable_index, yaw = data[p + 'stable_index'], data[p + 'yaw_rad']
    if len(offsets) != len(poses) + 1 or offsets[-1] != len(points) or len(scalars) != 6 or \
            points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f'inconsistent template arrays of obj_{obj_id:02d}')
    templates = [Template(points[a:b], None, None, poses[i], int(stable_index[i]),
                          float(yaw[i]))
                 for i, (a, b) in enumerate(zip(offsets[:-1], offsets[1:]))]
    mesh_vertices = mesh_faces = None
    if p + 'mesh_faces' in data.files:
        mesh_vertices = (data[p + 'mesh_vertices'].astype(np.float64) * POINT_QUANTUM_M
                         ).astype(np.float32)
        mesh_faces = data[p + 'mesh_faces'].astype(np.int32)
        if mesh_faces.ndim != 2 or mesh_faces.shape[1] != 3 or (
                mesh_faces.size and not 0 <= mesh_faces.min() <= mesh_faces.max() <
                len(mesh_vertices)):
            raise ValueError(f'inconsistent mesh arrays of obj_{obj_id:02d}')
    lookalikes = tuple(int(i) for i in data[p + 'lookalikes']) \
        if p + 'lookalikes' in data.files else ()
    return ObjectTemplates(
        obj_id=obj_id, diameter_m=float(scalars[0]), voxel_size_m=float(scalars[1]),
        model_points=(data[p + 'model_points'].astype(np.float64) * POINT_QUANTUM_M
                      ).astype(np.float32),
        model_normals=_unit(data[p + 'model_normals'].astype(np.float32) / NORMAL_SCALE),
        stable_poses=data[p + 'stable_poses'],
        stable_probabilities=data[p + 'stable_probabilities'],
        yaw_periods=data[p + 'yaw_periods'], templates=templates,
        normal_radius_voxels=float(scalars[2]), normal_max_nn=int(scalars[3]),
        fpfh_radius_voxels=float(scalars[4]), fpfh_max_nn=int(scalars[5]),
        lookalikes=lookalikes, mesh_vertices=mesh_vertices, mesh_faces=mesh_faces)


def compute_fpfh(points: np.ndarray, normals: np.ndarray, *, radius_m: float,
                 max_nn: int = 100) -> np.ndarray:
    """(N, 33) float32 FPFH descriptors of a cloud with normals (Rusu et al. 2009)."""
    if radius_m <= 0:
        raise ValueError(f'radius_m must be > 0, got {radius_m}')
    feature = o3d.pipelines.registration.compute_fpfh_feature(
        to_o3d(points, normals),
        search_param=o3d.geometry.KDTreeSearchParamHybrid(radius=float(radius_m),
                                                          max_nn=int(max_nn)))
    return np.asarray(feature.data, dtype=np.float32).T.copy()


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, *,
                   seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted uniform samples of a triangle mesh.

    Args:
        vertices: (V, 3) metres; faces: (F, 3) int, counter-clockwise seen from outside.
        count: number of samples.

    Returns:
        (count, 3) float32 points and (count, 3) float32 unit face normals.
    """
    vertices = np.asarray(vertices, np.float64)
    tri = vertices[np.asarray(faces, np.int64)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    if area.sum() <= 0:
        raise ValueError('the mesh has no area')
    rng = np.random.default_rng(seed)
    face = rng.choice(len(tri), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[face]
    points = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    normals = cross[face] / np.maximum(2.0 * area[face, None], 1e-15)
    return points.astype(np.float32), normals.astype(np.float32)


def _mesh_distance(vertices: np.ndarray, faces: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    scene = raycasting_scene(vertices, faces)

    def distance(points: np.ndarray) -> np.ndarray:
        query = o3d.core.Tensor(np.asarray(points, np.float32))
        return scene.compute_distance(query).numpy()
    return distance


def yaw_period(vertices: np.ndarray, faces: np.ndarray, T_table_object: np.ndarray, *,
               tolerance_m: float, samples: int = 500, seed: int = 0) -> float:
    """Rotational symmetry of a resting object about the table normal through its origin.

    Rotations by 2π/k (k = 36, 4, 3, 2) are tried; the symmetry holds when the rotated surface
    samples lie within ``tolerance_m`` of the mesh (95th percentile).

    Returns:
        the yaw period in radians: 0 for a continuous symmetry, 2π/k, or 2π for none.
    """
    points, _ = sample_surface(vertices, faces, samples, seed=seed)
    distance = _mesh_distance(vertices, faces)
    axis = invert_transform(T_table_object)[:3, :3] @ np.array([0.0, 0.0, 1.0])
    for k in (36, 4, 3, 2):
        R = rotation_about_axis(axis, 2.0 * np.pi / k)
        if np.percentile(distance(points @ R.T), 95) < tolerance_m:
            return CONTINUOUS_YAW_PERIOD if k == 36 else 2.0 * np.pi / k
    return 2.0 * np.pi


def merge_equivalent_poses(vertices: np.ndarray, faces: np.ndarray,
                           poses: list[tuple[np.ndarray, float]], *, tolerance_m: float,
                           samples: int = 300, yaw_steps: int = 72,
                           seed: int = 0) -> list[tuple[np.ndarray, float]]:
    """Merge stable poses that show the same resting shape up to a yaw (symmetric parts: a
    cylinder lying on its side has one hull facet per side); probabilities are summed.

    ``poses`` must be sorted most probable first; the first of each group is kept.
    """
    points, _ = sample_surface(vertices, faces, samples, seed=seed)
    distance = _mesh_distance(vertices, faces)
    yaws = 2.0 * np.pi * np.arange(yaw_steps) / yaw_steps
    kept: list[list] = []
    for T, prob in poses:
        for entry in kept:
            T_kept = entry[0]
            if abs(T_kept[2, 3] - T[2, 3]) > tolerance_m:
                continue  # different heights of the origin: different shapes
            # p on the surface; T p rotated by yaw back into the kept pose's object frame
            moved = [transform_points(invert_transform(T_kept) @ make_transform(
                rotation_about_axis([0, 0, 1], -y), np.zeros(3)) @ T, points) for y in yaws]
            d = distance(np.concatenate(moved)).reshape(len(yaws), -1)
            if np.min(np.percentile(d, 95, axis=1)) < tolerance_m:
                entry[1] += prob
                break
        else:
            kept.append([np.asarray(T, np.float64), float(prob)])
    return [(T, p) for T, p in kept]


def diameter(vertices: np.ndarray) -> float:
    """Largest distance between two vertices, metres."""
    return point_set_diameter(vertices)


def template_from_cloud(points_c: np.ndarray, T_camera_object: np.ndarray, *,
                        voxel_size_m: float, params: TemplateParams = TemplateParams(),
                        stable_index: int = -1, yaw_rad: float = 0.0,
                        with_fpfh: bool = False) -> Template:
    """A template from a captured or rendered partial cloud in its camera frame.

    Args:
        points_c: (N, 3) points of the object only, camera optical frame, metres.
        T_camera_object: (4, 4) pose of the object in that camera frame (e.g. from the
            turntable calibration).
        with_fpfh: compute the FPFH now (otherwise on first use).
    """
    points, normals = preprocess_roi(points_c, voxel_size_m=voxel_size_m, params=params.cloud)
    if len(points) < 10:
        raise ValueError(f'template view has only {len(points)} points after voxelisation; '
                         'is the object visible?')
    fpfh = compute_fpfh(points, normals, radius_m=params.fpfh_radius_voxels * voxel_size_m,
                        max_nn=params.fpfh_max_nn) if with_fpfh else None
    return Template(points.astype(np.float32), normals.astype(np.float32), fpfh,
                    np.asarray(T_camera_object, np.float64), stable_index, float(yaw_rad))


def build_object_templates(
        obj_id: int, vertices: np.ndarray, faces: np.ndarray,
        stable_poses: Iterable[tuple[np.ndarray, float]], *, intrinsics: CameraIntrinsics,
        T_world_camera: np.ndarray, params: TemplateParams = TemplateParams(),
        diameter_m: float | None = None,
        position_m: np.ndarray | None = None) -> ObjectTemplates:
    """Render the turntable templates of one object.

    The object rests on the table (world z = 0) at ``position_m`` (default: where the camera's
    optical axis meets the table) in each of its most probable stable poses and is turned by
    ``2π k / n_views``; each view is ray-cast from the camera, back-projected and voxelised
    (FPFH on first use).

    Args:
        obj_id: T-LESS id.
        vertices: (V, 3) mesh vertices in metres (object frame); faces: (F, 3) int.
        stable_poses: (T_table_object (4, 4), probability) pairs, e.g. from
            ``tlessbot_ros.io.models.stable_poses``.
        intrinsics, T_world_camera: the rendering camera (the rig's side camera).
        diameter_m: the object's diameter (computed from the vertices if None).
        position_m: (3,) turntable centre on the table in world coordinates.
    """
    from tlessbot_ros.core.common import MeshRenderer

    poses = sorted(((np.asarray(T, np.float64), float(p)) for T, p in stable_poses),
                   key=lambda pair: -pair[1])
    if not poses:
        raise ValueError(f'obj_{obj_id:02d}: at least one stable pose is needed')
    diam = float(diameter_m) if diameter_m else diameter(vertices)
    # Merge first: a part lying on its curved side has many hull facets, each improbable, that
    # together are often its most probable pose.
    poses = merge_equivalent_poses(vertices, faces, poses, tolerance_m=0.015 * diam)
    poses.sort(key=lambda pair: -pair[1])
    poses = [pair for pair in poses if pair[1] >= params.min_stable_probability] or poses[:1]
    voxel = diam * params.voxel_fraction
    model_points, model_normals = sample_surface(vertices, faces, params.model_samples,
                                                 seed=params.seed)
    periods = np.array([yaw_period(vertices, faces, T, tolerance_m=0.01 * diam)
                        for T, _ in poses])
    if position_m is None:
        position_m = _optical_axis_on_table(T_world_camera)
    T_camera_world = invert_transform(T_world_camera)
    templates = []
    for s, (T_table_object, _) in enumerate(poses[:params.max_stable_poses]):
        for k in range(params.n_views):
            yaw = 2.0 * np.pi * k / params.n_views
            T_world_object = make_transform(rotation_about_axis([0, 0, 1], yaw),
                                            position_m) @ T_table_object
            renderer = MeshRenderer()
            renderer.add_mesh(vertices, faces, T_world_object)
            view = renderer.render(intrinsics, T_world_camera)
            points, _ = depth_to_points(view.depth_m, intrinsics.K, mask=view.instance == 0)
            templates.append(template_from_cloud(
                points, T_camera_world @ T_world_object, voxel_size_m=voxel, params=params,
                stable_index=s, yaw_rad=yaw))
    return ObjectTemplates(
        obj_id=int(obj_id), diameter_m=diam, voxel_size_m=voxel, model_points=model_points,
        model_normals=model_normals, stable_poses=np.array([T for T, _ in poses]),
        stable_probabilities=np.array([p for _, p in poses]), yaw_periods=periods,
        templates=templates, normal_radius_voxels=params.cloud.normal_radius_voxels,
        normal_max_nn=params.cloud.normal_max_nn, fpfh_radius_voxels=params.fpfh_radius_voxels,
        fpfh_max_nn=params.fpfh_max_nn)


def _optical_axis_on_table(T_world_camera: np.ndarray) -> np.ndarray:
    origin, axis = T_world_camera[:3, 3], T_world_camera[:3, 2]
    if axis[2] >= -1e-6:
        raise ValueError('the camera does not look down at the table (z = 0)')
    return origin + axis * (-origin[2] / axis[2])


def build_database(models: Iterable[tuple[int, np.ndarray, np.ndarray,
                                          list[tuple[np.ndarray, float]], float | None]], *,
                   intrinsics: CameraIntrinsics, T_world_camera: np.ndarray,
                   params: TemplateParams = TemplateParams(),
                   progress: Callable[[Iterable], Iterable] | None = None) -> TemplateDatabase:
    """Templates of several objects: ``models`` yields (obj_id, vertices m, faces,
    stable poses, diameter_m or None); ``progress`` wraps the iterable (e.g. ``tqdm``)."""
    items = list(models)
    db = TemplateDatabase(params={**{k: v for k, v in asdict(params).items() if k != 'cloud'},
                                  'T_world_camera': np.asarray(T_world_camera).tolist(),
                                  'K': intrinsics.K.tolist(),
                                  'image_size': [intrinsics.width, intrinsics.height]})
    for obj_id, vertices, faces, poses, diam in (progress(items) if progress else items):
        db.objects[int(obj_id)] = build_object_templates(
            obj_id, vertices, faces, poses, intrinsics=intrinsics,
            T_world_camera=T_world_camera, params=params, diameter_m=diam)
    meshes = {int(obj_id): (vertices, faces) for obj_id, vertices, faces, _, _ in items}
    for obj_id, others in lookalike_pairs(meshes, tolerance_m=params.lookalike_tolerance_m,
                                          min_shared=params.lookalike_min_shared).items():
        obj = db.objects[obj_id]
        obj.lookalikes = others
        obj.mesh_vertices = np.asarray(meshes[obj_id][0], np.float32)
        obj.mesh_faces = np.asarray(meshes[obj_id][1], np.int32)
    return db


def resting_pose(vertices: np.ndarray) -> np.ndarray:
    """A simple ``T_table_object`` for tests and fall-backs: the object unrotated, lifted so
    its lowest vertex touches z = 0 (not necessarily a physically stable pose)."""
    return make_transform(np.eye(3), [0.0, 0.0, -float(np.min(np.asarray(vertices)[:, 2]))])


__all__ = ['TemplateParams', 'Template', 'ObjectTemplates', 'NearestGrid', 'TemplateDatabase',
           'compute_fpfh', 'sample_surface', 'yaw_period', 'merge_equivalent_poses', 'diameter',
           'template_from_cloud', 'build_object_templates', 'build_database', 'resting_pose']
