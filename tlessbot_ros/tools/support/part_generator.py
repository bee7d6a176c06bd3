"""Industrial parts made by code, written as STL in millimetres: a CAD folder that is not T-LESS.

Plates, brackets, blocks with holes and chamfers, a strip and a tube; some are near look-alikes
(one hole more, a longer leg), some 3 to 6 mm thick, and the flat ones have holes placed so
that their mirror image is a different part. Each part is a signed distance function (mm,
negative inside) meshed by marching cubes (Lorensen & Cline, SIGGRAPH 1987, as
``skimage.measure.marching_cubes``), then decimated: closed, manifold meshes.

    tlessbot parts generate --out my_cad
    tlessbot parts generate --out held_out --seed 7 --count 8   # drawn at random (part_family)
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from tlessbot_ros.io.parts import write_mesh

Sdf = Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]


def _box(centre, half, *, chamfer: float = 0.0) -> Sdf:
    """A box (mm) whose four edges parallel to z are cut by ``chamfer`` mm."""
    cx, cy, cz = centre
    hx, hy, hz = half

    def sdf(x, y, z):
        qx, qy, qz = np.abs(x - cx) - hx, np.abs(y - cy) - hy, np.abs(z - cz) - hz
        outside = np.sqrt(np.maximum(qx, 0) ** 2 + np.maximum(qy, 0) ** 2
                          + np.maximum(qz, 0) ** 2)
        d = outside + np.minimum(np.maximum(np.maximum(qx, qy), qz), 0.0)
        if chamfer > 0:
            cut = (np.abs(x - cx) + np.abs(y - cy) - (hx + hy - chamfer)) / np.sqrt(2.0)
            d = np.maximum(d, cut)
        return d
    return sdf


def _cylinder(centre, radius: float, half_length: float, axis: int = 2) -> Sdf:
    """A solid cylinder (mm) along ``axis`` (0 x, 1 y, 2 z)."""
    def sdf(x, y, z):
        p = [x - centre[0], y - centre[1], z - centre[2]]
        along = p.pop(axis)
        radial = np.hypot(p[0], p[1]) - radius
        axial = np.abs(along) - half_length
        return np.minimum(np.maximum(radial, axial), 0.0) + np.hypot(
            np.maximum(radial, 0.0), np.maximum(axial, 0.0))
    return sdf


def _union(*parts: Sdf) -> Sdf:
    return lambda x, y, z: np.min([p(x, y, z) for p in parts], axis=0)


def _minus(solid: Sdf, *holes: Sdf) -> Sdf:
    return lambda x, y, z: np.max([solid(x, y, z)] + [-h(x, y, z) for h in holes], axis=0)


def _holes(points, radius: float, depth: float = 200.0, axis: int = 2) -> list[Sdf]:
    return [_cylinder(p, radius, depth, axis) for p in points]


def _plate(length, width, thickness, holes, *, chamfer=4.0, radius=2.6) -> Sdf:
    return _minus(_box((0, 0, thickness / 2), (length / 2, width / 2, thickness / 2),
                       chamfer=chamfer),
                  *_holes([(x, y, 0) for x, y in holes], radius))


def _bracket(leg_a, leg_b, width, thickness, holes_a, holes_b) -> Sdf:
    base = _box((leg_a / 2, 0, thickness / 2), (leg_a / 2, width / 2, thickness / 2),
                chamfer=3.0)
    wall = _box((thickness / 2, 0, leg_b / 2), (thickness / 2, width / 2, leg_b / 2))
    cut = _holes([(x, y, 0) for x, y in holes_a], 2.6) + _holes(
        [(0, y, z) for y, z in holes_b], 2.6, axis=0)
    return _minus(_union(base, wall), *cut)


# The primitives, public for part_family.py (parts of the same kinds drawn from a seed)
box_sdf, cylinder_sdf, minus_sdf, bracket_sdf = _box, _cylinder, _minus, _bracket


def part_shapes() -> dict[str, tuple[Sdf, tuple[np.ndarray, np.ndarray]]]:
    """Name -> (signed distance function in mm, (low, high) bounds in mm)."""
    def bounds(low, high):
        return np.asarray(low, float), np.asarray(high, float)
    return {
        'plate_holes2': (_plate(60, 40, 4, [(-20, 10), (15, -10)]),
                         bounds((-31, -21, -1), (31, 21, 5))),
        'plate_holes3': (_plate(60, 40, 4, [(-20, 10), (15, -10), (15, 10)]),
                         bounds((-31, -21, -1), (31, 21, 5))),
        'strip_slotted': (_minus(_box((0, 0, 1.5), (40, 8, 1.5), chamfer=2.0),
                                 *_holes([(-30, 0, 0), (-22, 0, 0), (25, 3, 0)], 2.0)),
                          bounds((-41, -9, -1), (41, 9, 4))),
        'bracket_short': (_bracket(40, 30, 25, 5, [(28, -6), (28, 6)], [(0, 20)]),
                          bounds((-1, -13.5, -1), (41, 13.5, 31))),
        'bracket_long': (_bracket(55, 30, 25, 5, [(28, -6), (28, 6)], [(0, 20)]),
                         bounds((-1, -13.5, -1), (56, 13.5, 31))),
        'block_drilled': (_minus(_box((0, 0, 10), (20, 15, 10), chamfer=3.0),
                                 *_holes([(-10, 0, 0), (8, 5, 0)], 3.0),
                                 _cylinder((0, 0, 10), 2.5, 30, axis=0)),
                          bounds((-21, -16, -1), (21, 16, 21))),
        'disc_flange': (_minus(_cylinder((0, 0, 3), 22, 3),
                               *_holes([(0, 0, 0)], 6.0),
                               *_holes([(15, 0, 0), (-15, 0, 0), (0, 15, 0), (0, -15, 0)],
                                       2.2)),
                        bounds((-23, -23, -1), (23, 23, 7))),
        'tube': (_minus(_cylinder((0, 0, 0), 10, 25, axis=0), _cylinder((0, 0, 0), 7, 30, 0)),
                 bounds((-26, -11, -11), (26, 11, 11))),
    }


def mesh_part(sdf: Sdf, low: np.ndarray, high: np.ndarray, *, spacing_mm: float = 0.4
              ) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices (mm) and (F, 3) int32 faces of the surface sdf = 0: closed (no
    decimation, which opens holes), ~50k triangles for a part 60 mm long."""
    from skimage.measure import marching_cubes

    # The grid is shifted off the round coordinates so no sample lies exactly on a face.
    start = np.asarray(low, float) + 0.37 * spacing_mm
    axes = [np.arange(lo, hi + spacing_mm, spacing_mm) for lo, hi in zip(start, high)]
    x, y, z = np.meshgrid(*axes, indexing='ij')
    volume = sdf(x, y, z).astype(np.float32)
    verts, faces, _, _ = marching_cubes(volume, 0.0, spacing=(spacing_mm,) * 3,
                                        gradient_direction='ascent')
    # skimage orients the triangles toward the inside here: turned, the normals point out
    return verts + start, np.ascontiguousarray(faces[:, ::-1], dtype=np.int32)


def _rotation(axis, angle_deg: float, centre=(0.0, 0.0, 0.0)) -> list[float]:
    """A BOP ``symmetries_discrete`` entry: rotation about ``axis`` through ``centre`` (mm),
    the 4x4 flattened row by row."""
    from tlessbot_ros.core.common import rotation_about_axis

    R = rotation_about_axis(np.asarray(axis, float), np.radians(angle_deg))
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(centre) - R @ np.asarray(centre)
    return [round(float(v), 9) for v in T.ravel()]


bop_rotation = _rotation


def true_symmetries() -> dict[str, dict]:
    """The symmetries each part has by construction (BOP models_info entries, mm); a part not
    listed has none. ``disc_flange``: 4 holes on a circle (8 elements); ``tube``: about its
    axis, and end for end."""
    centre = (0.0, 0.0, 3.0)
    disc = [_rotation((0, 0, 1), a, centre) for a in (90, 180, 270)]
    disc += [_rotation((np.cos(np.radians(a)), np.sin(np.radians(a)), 0), 180, centre)
             for a in (0, 45, 90, 135)]
    return {'disc_flange': {'symmetries_discrete': disc},
            'tube': {'symmetries_continuous': [{'axis': [1, 0, 0], 'offset': [0, 0, 0]}],
                     'symmetries_discrete': [_rotation((0, 0, 1), 180)]}}


def generate_parts(out: str | Path, names: list[str] | None = None, *,
                   shapes: dict | None = None, symmetries: dict | None = None) -> list[Path]:
    """Write the parts (all, or ``names``) as ``<out>/<name>.stl`` in mm, and their true
    symmetries as ``<out>/symmetries.json`` (by name, as ``tlessbot parts build`` reads it);
    the STL paths. The 8 fixed example parts, or ``shapes`` (as :func:`part_shapes`) with
    their ``symmetries`` (by name; part_family.py draws such parts from a seed)."""
    import json

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if shapes is None:
        shapes, symmetries = part_shapes(), true_symmetries()
    listed = symmetries or {}
    paths = []
    for name in names or sorted(shapes):
        sdf, (low, high) = shapes[name]
        vertices, faces = mesh_part(sdf, low, high)
        paths.append(out / f'{name}.stl')
        write_mesh(paths[-1], vertices, faces)
    symmetries = {p.stem: listed.get(p.stem, {'symmetries_discrete': []}) for p in paths}
    (out / 'symmetries.json').write_text(json.dumps(symmetries, indent=1) + '\n')
    return paths
