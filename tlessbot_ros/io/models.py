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
from tlessbot_ros.core.common.resting import resting_poses
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
        others = sum(p.suffix.lower() in MODEL_SUFFIXES for p in folder.iterdir())
        hint = (f' ({others} meshes of other names: a CAD folder of your own parts is built '
                'first, tlessbot parts build --models CAD --out PARTS, then given as '
                'PARTS/models)') if others else ''
        raise ModelFileError(f'no obj_NN.stl|ply|obj model files in {folder}{hint}')
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

def stable_poses(model: ObjectModel, *, min_probability: float = 0.0,
                 merge_rolling: bool = False, rolling_angle_deg: float = 10.0
                 ) -> list[StablePose]:
    """Resting poses of ``model`` on a horizontal plane, most probable first.

    The quasi-static drop model of :func:`tlessbot_ros.core.common.resting.resting_poses` (the
    pose stage's resting-pose prior uses the same code).

    Results are cached on the model per option set.

    Returns:
        list of :class:`StablePose` with probability >= ``min_probability`` (renormalised to
        sum to 1).
    """
    key = ('stable_poses', float(min_probability), bool(merge_rolling), float(rolling_angle_deg))
    return model.cached(key, lambda: [StablePose(T, p) for T, p in resting_poses(
        model.vertices, model.faces, model.diameter_m, min_probability=min_probability,
        merge_rolling=merge_rolling, rolling_angle_deg=rolling_angle_deg)])
