"""The template database of the pose stage: what it stores per object, and its file format.

Each object gets N partial views (2–18, default 12; built by
:mod:`tlessbot_ros.core.pose.building`) rendered from its CAD model as the side camera sees it
resting on the table in a stable pose, or captured from real turntable clouds. A template stores
its voxelised cloud and the pose of the object in the template's camera frame; its normals
(facing the camera) and FPFH features (Rusu 2009) are computed on first use by the RANSAC path
and kept in memory, never stored (format version 2: they made most of a version-1 file). Per
object the database also keeps what the fast table-plane path of
:mod:`tlessbot_ros.core.pose.estimator` needs: surface samples with normals, the stable poses
on the table, and the yaw period of each stable pose (its rotational symmetry about the table
normal, detected from the mesh: 2π for none, π for a 180° flip, ~0 for a continuous axis).
:class:`ObjectTemplates` builds the lookup structures over the surface samples once and keeps
them (KD-tree, buckets, nearest-sample grid, float64 copies).

Files are ``.npz`` loaded with ``allow_pickle=False``; units are metres.

References:
    R. B. Rusu, N. Blodow, M. Beetz, "Fast Point Feature Histograms (FPFH) for 3D
    Registration", ICRA 2009.
"""
from __future__ import annotations

import json
import zipfile
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np
from scipy.spatial import cKDTree

from tlessbot_ros.core.pose.buckets import PointBuckets
from tlessbot_ros.core.pose.cloud import compute_fpfh, estimate_normals
from tlessbot_ros.core.pose.lookalike import LookalikeCheck
from tlessbot_ros.errors import ModelFileError

FORMAT = 'tlessbot_templates'
VERSION = 3
# Version 2 files (no look-alike meshes) still load; their parts are never checked as
# look-alikes.
READABLE_VERSIONS = (2, 3)
CONTINUOUS_YAW_PERIOD = 0.0
# Storage: points as int16 multiples of 0.05 mm (10x below the sensor noise), unit normals as
# int8 / 127; this, and no stored FPFH, keeps all 23 T-LESS objects near 1 MB.
POINT_QUANTUM_M = 5e-5
NORMAL_SCALE = 127.0


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
        listed_yaw_periods: (S,) float64 the yaw periods the part's listed symmetries give
            (models_info.json; exact, where ``yaw_periods`` are what the depth cannot tell
            apart); None when none were listed.
        listed_rotations: (K, 3, 3) float64 the rotations of the part's listed symmetries
            (continuous axes sampled every 2°), the identity first; None when none were listed.
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
    listed_yaw_periods: np.ndarray | None = None
    listed_rotations: np.ndarray | None = None
    _cache: dict[Hashable, Any] = field(default_factory=dict, repr=False, compare=False)

    def exact_yaw_period(self) -> float:
        """The yaw period resting in the most probable stable pose, radians: the listed
        symmetries' where the templates hold it (a disc with four small holes: a quarter
        turn, which the depth reads as continuous), else the depth's; 2π for none."""
        periods = self.yaw_periods if self.listed_yaw_periods is None else \
            self.listed_yaw_periods
        return float(periods[0]) if len(periods) else 2.0 * np.pi

    def features(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        """Normals (N, 3) and FPFH (N, 33) float32 of template ``index``, computed on the first
        call and kept on the template."""
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

    def model_subset(self, count: int = 800) -> tuple[np.ndarray, np.ndarray]:
        """float64 (count, 3) points and normals: the first ``count`` surface samples (they are
        in random order) for cheap scoring (converted once per count)."""
        key = ('subset', count)
        if key not in self._cache:
            self._cache[key] = (self.model_points[:count].astype(np.float64),
                                self.model_normals[:count].astype(np.float64))
        return cast(tuple[np.ndarray, np.ndarray], self._cache[key])

    def derived(self, key: Hashable, build: Callable[[], Any]) -> Any:
        """A value computed from this object's fixed data alone (e.g. the table path's
        hypotheses before they meet a scene), built by ``build()`` on the first call for
        ``key`` and kept; callers must not modify it."""
        key = ('derived', key)
        if key not in self._cache:
            self._cache[key] = build()
        return self._cache[key]

    def derived_items(self) -> dict[tuple[Any, ...], Any]:
        """The values :meth:`derived` has built so far, by key."""
        return {key[1]: value for key, value in self._cache.items()
                if isinstance(key, tuple) and len(key) == 2 and key[0] == 'derived'}

    def adopt_derived(self, key: Hashable, value: Any) -> None:
        """Keep ``value`` as :meth:`derived`'s for ``key`` (restored from a cache)."""
        self._cache[('derived', key)] = value

    def model_arrays_float64(self) -> tuple[np.ndarray, np.ndarray]:
        """float64 ``(model_normals, model_points)``, (M, 3) each (converted once)."""
        if 'float64' not in self._cache:
            self._cache['float64'] = (self.model_normals.astype(np.float64),
                                      self.model_points.astype(np.float64))
        return cast(tuple[np.ndarray, np.ndarray], self._cache['float64'])

    def sample_spacing_m(self) -> float:
        """Median distance (m) from a model sample to its nearest neighbour (computed once)."""
        def build() -> float:
            distance, _ = self.model_tree().query(self.model_points.astype(np.float64), k=2)
            return float(np.median(distance[:, 1]))
        return cast(float, self.derived('sample_spacing', build))

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
        return cast(PointBuckets, self._cache[key])

    def nearest_grid(self, spacing_m: float | None = None) -> NearestGrid:
        """A voxel grid of the nearest model sample of every cell (built once per spacing)."""
        spacing = float(spacing_m or self.voxel_size_m / 2.0)
        key = self._grid_key(spacing)
        if key not in self._cache:
            self._cache[key] = NearestGrid.build(self.model_points, spacing,
                                                 margin_m=4.0 * self.voxel_size_m,
                                                 tree=self.model_tree())
        return cast(NearestGrid, self._cache[key])

    def adopt_nearest_grid(self, grid: NearestGrid) -> None:
        """Use ``grid`` (built earlier by :meth:`nearest_grid` for these samples, e.g. read
        back from a cache) as the grid of its spacing."""
        self._cache[self._grid_key(grid.spacing)] = grid

    @staticmethod
    def _grid_key(spacing_m: float) -> tuple[str, float]:
        return 'grid', round(float(spacing_m), 6)


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
    params: dict[str, Any] = field(default_factory=dict)

    def __getitem__(self, obj_id: int) -> ObjectTemplates:
        try:
            return self.objects[int(obj_id)]
        except KeyError:
            raise KeyError(f'no templates for obj_{int(obj_id):02d}; the database has '
                           f'{sorted(self.objects)}') from None

    def precompute_features(self, ids: Iterable[int] | None = None) -> None:
        """Compute every template's normals and FPFH now instead of on first use, so the first
        RANSAC fallback of an object is not slower than later ones."""
        for obj_id in (self.objects if ids is None else ids):
            obj = self[obj_id]
            for index in range(len(obj.templates)):
                obj.features(index)

    def __contains__(self, obj_id: object) -> bool:
        return obj_id in self.objects

    def extents_m(self) -> np.ndarray | None:
        """(N, 3) the box extents of its objects' model points, metres (None: no objects)."""
        if not self.objects:
            return None
        return np.array([np.ptp(o.model_points, axis=0) for o in self.objects.values()])

    def lookalike_check(self, *, tolerance_m: float = 0.002, min_z: float = 0.0
                        ) -> LookalikeCheck:
        """A :class:`~tlessbot_ros.core.pose.LookalikeCheck` over the stored look-alikes
        (it checks nothing for a database without any); the options are its own."""
        objects = [o for o in self.objects.values() if o.lookalikes and o.mesh_faces is not None]
        return LookalikeCheck({o.obj_id: (vertices, faces) for o in objects
                               if (vertices := o.mesh_vertices) is not None
                               and (faces := o.mesh_faces) is not None},
                              {o.obj_id: o.lookalikes for o in objects}, tolerance_m=tolerance_m,
                              min_z=min_z)

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
            if obj.listed_yaw_periods is not None:
                arrays[p + 'listed_yaw_periods'] = np.asarray(obj.listed_yaw_periods, np.float64)
            if obj.listed_rotations is not None:
                arrays[p + 'listed_rotations'] = np.asarray(obj.listed_rotations,
                                                            np.float64).reshape(-1, 3, 3)
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
            # (numpy's stub types **kwds so that they could be its allow_pickle: bool)
            np.savez_compressed(stream, **arrays)  # type: ignore[arg-type]

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
    return cast(np.ndarray, q.astype(np.int16))


def _unit(vectors: np.ndarray) -> np.ndarray:
    unit: np.ndarray = vectors / np.maximum(np.linalg.norm(vectors, axis=1, keepdims=True), 1e-9)
    return unit


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
    listed = data[p + 'listed_yaw_periods'] if p + 'listed_yaw_periods' in data.files else None
    if listed is not None and listed.shape != data[p + 'yaw_periods'].shape:
        raise ValueError(f'inconsistent yaw periods of obj_{obj_id:02d}')
    rotations = data[p + 'listed_rotations'] if p + 'listed_rotations' in data.files else None
    if rotations is not None and (rotations.ndim != 3 or rotations.shape[1:] != (3, 3)):
        raise ValueError(f'inconsistent listed rotations of obj_{obj_id:02d}')
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
        lookalikes=lookalikes, mesh_vertices=mesh_vertices, mesh_faces=mesh_faces,
        listed_yaw_periods=listed, listed_rotations=rotations)
