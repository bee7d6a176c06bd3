"""Flat test parts made by code: plates, brackets and a spanner 3-6 mm thick, two blocks.

Each part is a signed distance field (2-D outline with holes, extruded, the top edges chamfered)
turned into a closed triangle mesh by marching cubes, then decimated. The set is asymmetric in
the plane (a part turned upside down shows its mirror outline), and ``obj_02`` is a near
look-alike of ``obj_01`` (one hole more). Written as ``obj_NN.stl`` in millimetres, as
``tlessbot simulate`` / ``train`` / ``templates`` read them:

    python -m tlessbot_ros.tools.support.flat_parts OUT_DIR
"""
from __future__ import annotations

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np

Field = Callable[[np.ndarray, np.ndarray], np.ndarray]   # (x, y) mm -> signed distance mm


def box(cx: float, cy: float, w: float, h: float, angle_deg: float = 0.0) -> Field:
    a = np.radians(angle_deg)

    def field(x, y):
        u = np.cos(a) * (x - cx) + np.sin(a) * (y - cy)
        v = -np.sin(a) * (x - cx) + np.cos(a) * (y - cy)
        qx, qy = np.abs(u) - w / 2, np.abs(v) - h / 2
        return np.hypot(np.maximum(qx, 0), np.maximum(qy, 0)) + np.minimum(np.maximum(qx, qy), 0)
    return field


def circle(cx: float, cy: float, r: float) -> Field:
    return lambda x, y: np.hypot(x - cx, y - cy) - r


def capsule(x0: float, y0: float, x1: float, y1: float, r: float) -> Field:
    def field(x, y):
        dx, dy = x1 - x0, y1 - y0
        t = np.clip(((x - x0) * dx + (y - y0) * dy) / (dx * dx + dy * dy), 0, 1)
        return np.hypot(x - x0 - t * dx, y - y0 - t * dy) - r
    return field


def polygon(points: list[tuple[float, float]]) -> Field:
    """Convex polygon, corners counter-clockwise (max of the edges' half-plane distances)."""
    p = np.asarray(points, np.float64)

    def field(x, y):
        d = np.full(np.shape(x), -np.inf)
        for (ax, ay), (bx, by) in zip(p, np.roll(p, -1, axis=0)):
            nx, ny = by - ay, -(bx - ax)
            n = np.hypot(nx, ny)
            d = np.maximum(d, ((x - ax) * nx + (y - ay) * ny) / n)
        return d
    return field


def union(*fields: Field) -> Field:
    return lambda x, y: np.min([f(x, y) for f in fields], axis=0)


def minus(shape: Field, *holes: Field) -> Field:
    return lambda x, y: np.max([shape(x, y)] + [-h(x, y) for h in holes], axis=0)


# name -> (outline, thickness mm, top chamfer mm)
PARTS: dict[int, tuple[Field, float, float]] = {
    # plate with two unequal holes and one corner cut off
    1: (minus(box(0, 0, 90, 50), circle(-30, 12, 4), circle(20, -8, 6),
              box(45, 25, 24, 24, 45)), 4.0, 0.8),
    # near look-alike of 1: one hole more
    2: (minus(box(0, 0, 90, 50), circle(-30, 12, 4), circle(20, -8, 6), circle(0, 14, 3),
              box(45, 25, 24, 24, 45)), 4.0, 0.8),
    # L bracket, arms of unequal length, three holes
    3: (minus(union(box(0, 0, 80, 20), box(-30, 25, 20, 70)), circle(25, 0, 4),
              circle(-30, 45, 4), circle(-30, 10, 3)), 5.0, 1.0),
    # spanner: a handle, a ring end with a hexagonal hole, an open jaw turned 15 degrees
    4: (minus(union(capsule(-45, 0, 45, 0, 7), circle(-50, 0, 13), circle(52, 0, 14)),
              polygon([(-50 + 7 * np.cos(a), 7 * np.sin(a))
                       for a in np.radians(np.arange(0, 360, 60))]),
              box(62, 3, 22, 11, 15)), 4.0, 0.6),
    # triangular gusset with a slot
    5: (minus(polygon([(-35, -25), (35, -25), (-35, 30)]), circle(-22, -12, 4),
              capsule(-5, -14, 12, -14, 3), circle(-24, 14, 3)), 6.0, 1.0),
    # thin plate with a slot and a notch on one side
    6: (minus(box(0, 0, 60, 40), capsule(-15, 5, 10, 5, 4), box(20, -20, 10, 12),
              circle(-20, -10, 3)), 3.0, 0.5),
    # thick block, off-centre hole
    7: (minus(box(0, 0, 50, 30), circle(12, 4, 6)), 20.0, 1.5),
    # thick L-shaped block
    8: (minus(union(box(0, 0, 45, 15), box(-15, 12, 15, 35)), circle(12, 0, 3.5)), 15.0, 1.5),
}


def part_mesh(outline: Field, thickness_mm: float, chamfer_mm: float, *,
              step_mm: float = 0.4, faces: int = 12000) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float64 vertices (mm, resting on z = 0) and (F, 3) int faces of one part."""
    import open3d as o3d
    from skimage.measure import marching_cubes

    extent = 75.0
    xs = np.arange(-extent, extent + step_mm, step_mm)
    zs = np.arange(-2 * step_mm, thickness_mm + 3 * step_mm, step_mm)
    X, Y = np.meshgrid(xs, xs, indexing='ij')
    d2 = outline(X, Y)[..., None]
    Z = zs[None, None, :]
    d = np.maximum(d2, np.maximum(-Z, Z - thickness_mm))
    d = np.maximum(d, (d2 + Z - thickness_mm + chamfer_mm) / np.sqrt(2.0))
    vertices, tris, _, _ = marching_cubes(d.astype(np.float32), 0.0,
                                          spacing=(step_mm, step_mm, step_mm))
    vertices += np.array([xs[0], xs[0], zs[0]])
    vertices, tris = _clean(vertices, tris)
    mesh = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(vertices),
                                     o3d.utility.Vector3iVector(tris.astype(np.int32)))
    mesh = mesh.simplify_quadric_decimation(faces)
    v, f = _clean(np.asarray(mesh.vertices), np.asarray(mesh.triangles))
    v -= np.array([*(v.min(axis=0)[:2] + v.max(axis=0)[:2]) / 2, 0.0])
    return v, f


def _clean(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Without zero-area faces (marching cubes makes some), vertices merged."""
    import trimesh

    mesh = trimesh.Trimesh(vertices, faces, process=True)
    mesh.update_faces(mesh.nondegenerate_faces())
    mesh.merge_vertices()
    mesh.remove_unreferenced_vertices()
    return np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)


def write_parts(out: Path, ids: list[int] | None = None) -> list[Path]:
    """Write ``obj_NN.stl`` (mm) for the parts ``ids`` (default all) into ``out``, and a BOP
    ``models_info.json`` that lists no symmetry: none of them has one (a plate turned over
    shows its mirror outline), though a detector that tolerates small features may call a
    thin plate 2-fold about its in-plane axes and score a turned-over pose as right."""
    import json

    import trimesh

    out.mkdir(parents=True, exist_ok=True)
    paths, info = [], {}
    for obj_id in ids or sorted(PARTS):
        vertices, faces = part_mesh(*PARTS[obj_id])
        path = out / f'obj_{obj_id:02d}.stl'
        mesh = trimesh.Trimesh(vertices, faces, process=True)
        mesh.export(path)
        paths.append(path)
        hull = mesh.convex_hull.vertices
        lo, size = mesh.bounds[0], mesh.extents
        info[str(obj_id)] = {
            'diameter': float(np.max(np.linalg.norm(hull[:, None] - hull[None], axis=-1))),
            'min_x': float(lo[0]), 'min_y': float(lo[1]), 'min_z': float(lo[2]),
            'size_x': float(size[0]), 'size_y': float(size[1]), 'size_z': float(size[2]),
            'symmetries_discrete': []}
    (out / 'models_info.json').write_text(json.dumps(info, indent=2) + '\n')
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('out', type=Path, help='folder to write obj_NN.stl into')
    parser.add_argument('--ids', type=int, nargs='+', help='only these parts')
    args = parser.parse_args(argv)
    for path in write_parts(args.out, args.ids):
        print(path)
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
