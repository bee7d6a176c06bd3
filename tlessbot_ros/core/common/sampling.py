"""Area-weighted uniform random points on a triangle mesh.

The one surface sampler of the package: the template database's model samples, the symmetry
detector's query and reference sets, the look-alike surface comparison, the simulator's
convex-hull samples and the benchmarks' metric points all come from :func:`sample_surface`.

A point in a triangle (a, b, c) is ``a + u (b - a) + v (c - a)`` with (u, v) uniform in the
unit triangle. Two classic ways to draw (u, v) are kept, because stored results depend on them
(the same seed gives other points with the other scheme):

* ``'reflect'``: u, v uniform in the unit square, reflected into the triangle when
  u + v > 1 (the template database, ``tlessbot templates``);
* ``'sqrt'``: barycentric (1 - sqrt(r1), sqrt(r1) (1 - r2), sqrt(r1) r2) of uniform r1, r2
  (Osada et al., "Shape distributions", ACM TOG 21(4), 2002, eq. 1); the symmetry detector,
  the look-alike comparison and the simulator.
"""
from __future__ import annotations

import numpy as np

SAMPLING_SCHEMES = ('reflect', 'sqrt')


def sample_surface(vertices: np.ndarray, faces: np.ndarray, count: int, *, seed: int = 0,
                   scheme: str = 'reflect') -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted uniform samples of a triangle mesh.

    Args:
        vertices: (V, 3) vertex positions (any unit; metres in this package).
        faces: (F, 3) int vertex indices, counter-clockwise seen from outside.
        count: number of samples.
        seed: seed of the random generator (faces are drawn first, then the points in them).
        scheme: how a point is drawn inside its face, ``'reflect'`` or ``'sqrt'`` (see the
            module docstring; both are uniform, they differ in the points a seed gives).

    Returns:
        (count, 3) float64 points in the unit of ``vertices`` and (count, 3) float64 unit
        face normals (outward for counter-clockwise faces).
    """
    if scheme not in SAMPLING_SCHEMES:
        raise ValueError(f'scheme must be one of {SAMPLING_SCHEMES}, got {scheme!r}')
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or faces.ndim != 2 or faces.shape[1] != 3:
        raise ValueError('vertices must be (V, 3) and faces (F, 3)')
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    if area.sum() <= 0:
        raise ValueError('the mesh has no area')
    rng = np.random.default_rng(seed)
    face = rng.choice(len(tri), size=count, p=area / area.sum())
    t = tri[face]
    if scheme == 'reflect':
        u, v = rng.random(count), rng.random(count)
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        points = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    else:
        r1 = np.sqrt(rng.random(count))
        r2 = rng.random(count)
        points = ((1 - r1)[:, None] * t[:, 0] + (r1 * (1 - r2))[:, None] * t[:, 1]
                  + (r1 * r2)[:, None] * t[:, 2])
    normals = cross[face] / np.maximum(2.0 * area[face, None], 1e-15)
    return points, normals
