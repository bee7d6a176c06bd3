"""A parts folder: everything a cell needs to find its own parts, written by ``tlessbot parts
build`` and named by the graph's ``parts_path`` parameter.

Layout (all files written by us; the meshes are the user's, converted)::

    PARTS/manifest.json     format, parts (name, id, size, symmetry, look-alikes), the rig it
                            was built for, the recipe, a fingerprint of the CAD files
    PARTS/classifier.npz    tlessbot train
    PARTS/templates.npz     tlessbot templates, for the rig's side camera
    PARTS/models/           obj_NN.ply (mm) + models_info.json (BOP: diameters, symmetries)

A part's id is the number of an ``obj_NN`` file (T-LESS and BOP keep theirs); other files get
the free ids 1, 2, ... in the order of their names. Its name is the file's stem.
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tlessbot_ros.core.common.names import check_part_name
from tlessbot_ros.errors import ModelFileError, PartNameError, TlessbotError
from tlessbot_ros.io.models import MODEL_SUFFIXES, object_id_from_path, read_mesh

if TYPE_CHECKING:
    from tlessbot_ros.core.common import Rig

FORMAT = 'tlessbot-parts/1'
MANIFEST = 'manifest.json'
CLASSIFIER = 'classifier.npz'
TEMPLATES = 'templates.npz'
MODELS = 'models'
REQUIRED = (MANIFEST, CLASSIFIER, TEMPLATES, f'{MODELS}/models_info.json')
UNITS = {'mm': 1e-3, 'm': 1.0}
# A part smaller than this, or larger, is taken as a file in other units (x1000).
MIN_DIAMETER_M, MAX_DIAMETER_M = 0.004, 1.5
# Rig tolerances a parts folder accepts: its templates are views of the side camera.
RIG_POSITION_TOL_M, RIG_ANGLE_TOL_DEG, RIG_FOCAL_TOL = 0.02, 2.0, 0.03


class PartsFolderError(TlessbotError):
    """A parts folder is missing a file, is damaged, or was built for another rig."""


@dataclass(frozen=True)
class CadPart:
    """One CAD file of a user's folder: ``name`` (its stem), ``obj_id``, ``path``."""

    name: str
    obj_id: int
    path: Path


def cad_parts(folder: str | Path) -> list[CadPart]:
    """The STL / PLY / OBJ files of ``folder`` as parts, by id.

    Raises:
        ModelFileError: no folder, no mesh files, or two files with one stem.
        PartNameError: a stem that cannot name a ROS topic (the message says how to rename).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ModelFileError(f'CAD folder not found: {folder}')
    files = [p for p in sorted(folder.iterdir())
             if p.is_file() and p.suffix.lower() in MODEL_SUFFIXES]
    if not files:
        raise ModelFileError(f'no .stl, .ply or .obj files in {folder}')
    by_stem: dict[str, Path] = {}
    bad: list[str] = []
    for path in files:
        if path.stem in by_stem:
            raise ModelFileError(f'{by_stem[path.stem].name} and {path.name} have the same '
                                 'name: keep one of them')
        try:
            check_part_name(path.stem, source=path.name)
        except PartNameError as error:
            bad.append(str(error))
        by_stem[path.stem] = path
    if bad:   # every file to rename at once, not one per try
        raise PartNameError(problems_listed(bad, len(files)))
    fixed = {object_id_from_path(p): p for p in files if object_id_from_path(p) is not None}
    free = (i for i in range(1, 10_000) if i not in fixed)
    parts = [CadPart(p.stem, object_id_from_path(p) or next(free), p) for p in files]
    names = {}
    for part in parts:
        if part.obj_id in names:
            raise PartNameError(f'{names[part.obj_id]} and {part.name} both have id '
                                f'{part.obj_id}: rename one')
        names[part.obj_id] = part.name
    return sorted(parts, key=lambda p: p.obj_id)


def model_names(models: str | Path) -> dict[int, str]:
    """{id: name} of the parts of a models folder that have names of their own: a parts
    folder's ``models/`` (its manifest's names) or a CAD folder (the file stems, as
    :func:`cad_parts`); the ``obj_NN`` files of T-LESS and BOP folders are left out (they keep
    the default name), and so is a folder whose names cannot be read (then all are obj_NN)."""
    models = Path(models)
    manifest = models.parent / MANIFEST
    try:
        if models.name == MODELS and manifest.is_file():
            folder = PartsFolder(models.parent, json.loads(manifest.read_text(encoding='utf-8')))
            names = folder.names
            for name in names.values():
                check_part_name(name)
            return names
        return {p.obj_id: p.name for p in cad_parts(models)
                if object_id_from_path(p.path) is None}
    except (OSError, ValueError, KeyError, TypeError, ModelFileError, PartNameError):
        return {}


def problems_listed(problems: list[str], files: int) -> str:
    """One problem of a CAD folder as it is; several as a count of the ``files`` that
    cannot be used and one indented line each (the user fixes them all in one go)."""
    if len(problems) == 1:
        return problems[0]
    return (f'{len(problems)} of {files} CAD files cannot be used:\n  '
            + '\n  '.join(problems))


def read_part_mesh(path: Path, *, units: str = 'mm'
                   ) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """(V, 3) float64 vertices in metres, (F, 3) int32 faces and the warnings of one part,
    checked by :func:`check_part_mesh`."""
    if units not in UNITS:
        raise TlessbotError(f'units must be one of {sorted(UNITS)}, got {units!r}')
    vertices, faces = read_mesh(path)
    vertices = vertices * UNITS[units]
    return vertices, faces, check_part_mesh(vertices, faces, name=path.name, units=units)


def check_part_mesh(vertices: np.ndarray, faces: np.ndarray, *, name: str,
                    units: str = 'mm', max_open_fraction: float = 0.2,
                    max_rim_fraction: float = 0.5) -> list[str]:
    """Refuse a mesh the pipeline cannot use, with what to do about it; warn of a mesh with
    holes (rendering and the resting poses still work on it: they use the convex hull).

    Args:
        vertices: (V, 3) metres; faces: (F, 3) vertex indices.
        max_open_fraction: share of edges on a hole (used by one triangle only) above which
            the mesh is a sheet, not a solid.
        max_rim_fraction: length of the holes' rims, relative to the part's size (its box's
            diagonal), above which a mesh with few open edges is warned of.

    Returns:
        warnings, one line each (empty for a closed mesh).

    Raises:
        ModelFileError: wrong units by 1000x, degenerate (flat or zero area), or open.
    """
    extent = np.ptp(vertices, axis=0)
    size = float(np.linalg.norm(extent))
    if size < MIN_DIAMETER_M or size > MAX_DIAMETER_M:
        # --units is the whole folder's: one file in other units is scaled, not the folder
        if units == 'mm' and size < MIN_DIAMETER_M:
            hint = ('its file is probably in m; --units m if all the files are in m, else '
                    'scale it to mm (x1000)')
        elif units == 'm' and size > MAX_DIAMETER_M:
            hint = ('its file is probably in mm; leave out --units m if all the files are in '
                    'mm, else scale it to m (x0.001)')
        else:
            hint = (f'a part is {1000 * MIN_DIAMETER_M:.0f} mm to {MAX_DIAMETER_M:g} m across: '
                    'check its units (mm, or m with --units m)')
        raise ModelFileError(f'{name} is {size:.4g} m across read in {units}: {hint}')
    tri = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if extent.min() < 1e-4 or area.sum() <= 0:
        raise ModelFileError(f'{name} is degenerate (thinner than 0.1 mm or without area): '
                             'export the part as a solid')
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]),
                    axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    open_fraction = float(np.mean(counts == 1))
    # a fine mesh with a large hole has few open edges but a long hole rim: warn on either
    rim = unique[counts == 1]
    rim_m = float(np.linalg.norm(vertices[rim[:, 0]] - vertices[rim[:, 1]], axis=1).sum())
    what = (f'{name} is not closed ({100 * open_fraction:.1f} % of its edges border a hole, '
            f'{1000 * rim_m:.0f} mm of hole rim on a part {1000 * size:.0f} mm across): '
            'export it as a closed solid (or close the holes, e.g. MeshLab "Close Holes")')
    if open_fraction > max_open_fraction:
        raise ModelFileError(what)
    return [what] if open_fraction > 0.01 or rim_m > max_rim_fraction * size else []


def write_mesh(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """A binary mesh file (STL or PLY by its suffix) in the vertices' own units.

    Raises:
        ModelFileError: it cannot be written.
    """
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(np.asarray(vertices, float)),
                                     o3d.utility.Vector3iVector(np.asarray(faces, np.int32)))
    mesh.compute_triangle_normals()
    if not o3d.io.write_triangle_mesh(str(path), mesh):
        raise ModelFileError(f'cannot write {path}')


def cad_fingerprint(parts: list[CadPart], *, units: str) -> str:
    """SHA-256 (hex) of the CAD files' names, bytes and units: a parts set's identity."""
    digest = hashlib.sha256(f'{FORMAT} {units}'.encode())
    for part in parts:
        digest.update(f'\n{part.obj_id} {part.name}\n'.encode())
        digest.update(part.path.read_bytes())
    return digest.hexdigest()


def rig_summary(rig: Rig) -> dict[str, Any]:
    """The rig as the manifest stores it: per camera its pose (4x4) and intrinsics."""
    return {name: {'T_world_camera': np.round(cam.T_world_camera, 6).tolist(),
                   'width': cam.intrinsics.width, 'height': cam.intrinsics.height,
                   'K': np.round(cam.intrinsics.K, 4).tolist()}
            for name, cam in sorted(rig.cameras.items())}


def rig_difference(built: dict[str, Any], T_world_camera: np.ndarray, *,
                   focal_px: float | None = None, width: int | None = None,
                   camera: str = 'side') -> str | None:
    """Why a ``camera`` at ``T_world_camera`` (4x4, metres; with ``focal_px`` and ``width``
    when known) differs from the one a folder was built for; None: the same, within
    RIG_POSITION_TOL_M, RIG_ANGLE_TOL_DEG and RIG_FOCAL_TOL."""
    if camera not in built:
        return f'the manifest has no {camera} camera'
    T_built = np.asarray(built[camera]['T_world_camera'], float)
    T = np.asarray(T_world_camera, float)
    moved = float(np.linalg.norm(T_built[:3, 3] - T[:3, 3]))
    cos = (np.trace(T_built[:3, :3].T @ T[:3, :3]) - 1.0) / 2.0
    turned = float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
    if moved > RIG_POSITION_TOL_M or turned > RIG_ANGLE_TOL_DEG:
        return (f'its {camera} camera stood {100 * moved:.0f} cm and {turned:.0f} deg away '
                "from this rig's")
    built_focal = float(np.asarray(built[camera]['K'])[0][0])
    if (focal_px is not None and abs(focal_px / built_focal - 1.0) > RIG_FOCAL_TOL) or \
            (width is not None and built[camera]['width'] != width):
        return f'its {camera} camera had another focal length or image size'
    return None


@dataclass(frozen=True)
class PartsFolder:
    """An opened, checked parts folder."""

    path: Path
    manifest: dict[str, Any]

    @property
    def classifier(self) -> Path:
        return self.path / CLASSIFIER

    @property
    def templates(self) -> Path:
        return self.path / TEMPLATES

    @property
    def models(self) -> Path:
        return self.path / MODELS

    @property
    def names(self) -> dict[int, str]:
        """{id: name} of its parts."""
        return {int(p['id']): str(p['name']) for p in self.manifest['parts']}

    @property
    def extents_m(self) -> np.ndarray:
        """(N, 3) its parts' box extents in metres (the manifest's ``size_mm``)."""
        return np.array([p['size_mm'] for p in self.manifest['parts']], float).reshape(-1, 3) \
            * 1e-3


def write_manifest(folder: Path, manifest: dict[str, Any]) -> Path:
    path = folder / MANIFEST
    path.write_text(json.dumps(dict(manifest, format=FORMAT), indent=1) + '\n')
    return path


def open_parts_folder(path: str | Path, *, rig: Rig | None = None,
                      side_pose: np.ndarray | None = None) -> PartsFolder:
    """The parts folder at ``path``, refused with a one-line reason when a file is missing, the
    manifest is not ours, a name is invalid, or it was built for another rig than ``rig`` (or
    another side camera pose than ``side_pose``, 4x4 T_world_camera; a node knows only that
    before its first CameraInfo).

    Raises:
        PartsFolderError: the reason, and what to do.
    """
    path = Path(path)
    if not path.is_dir():
        raise PartsFolderError(f'parts folder not found: {path}')
    for name in REQUIRED:
        if not (path / name).is_file():
            raise PartsFolderError(f'parts folder {path} has no {name}: rebuild it with '
                                   'tlessbot parts build')
    try:
        manifest = json.loads((path / MANIFEST).read_text(encoding='utf-8'))
        if manifest.get('format') != FORMAT:
            raise ValueError(f'format {manifest.get("format")!r}, want {FORMAT!r}')
        folder = PartsFolder(path, manifest)
        for name in folder.names.values():
            check_part_name(name)
    except (ValueError, KeyError, TypeError, AttributeError, PartNameError) as error:
        raise PartsFolderError(f'{path / MANIFEST} is not a usable manifest: {error}') from None
    why = None
    if rig is not None:
        side = rig['side']
        why = rig_difference(manifest.get('rig', {}), side.T_world_camera,
                             focal_px=side.intrinsics.K[0, 0], width=side.intrinsics.width)
    elif side_pose is not None:
        why = rig_difference(manifest.get('rig', {}), side_pose)
    if why is not None:
        raise PartsFolderError(f'parts folder {path} was built for another rig ({why}): '
                               'rebuild it with tlessbot parts build --config YOUR_CELL.yaml')
    return folder
