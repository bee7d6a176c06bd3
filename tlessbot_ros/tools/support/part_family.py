"""A family of parts drawn at random from a seed: held-out parts nobody looked at while writing
the rules (``tlessbot parts generate --seed N --count K``).

The same kinds as the fixed example parts (plates, strips, brackets, blocks, flanged discs,
tubes) with random dimensions, hole and slot layouts and chamfers; the flat ones 3 to 6 mm
thick. The family holds near look-alike pairs: a plate and its twin with one hole less, and a
bracket and its mirror image. Each part is a spec (plain numbers, mm) turned into a signed
distance function; a drawn layout that a turn of the part's box (quarter, half, diagonal)
maps onto itself (within 2 mm) is drawn again, so the parts have exactly the symmetries
listed (discs and tubes by construction, the others none). The same seed and count give
the same parts.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from tlessbot_ros.tools.support.part_generator import (
    Sdf,
    bop_rotation,
    box_sdf,
    bracket_sdf,
    cylinder_sdf,
    generate_parts,
    minus_sdf,
)

KINDS = ('plate', 'strip', 'bracket', 'block', 'disc', 'tube')
FLAT_KINDS = ('plate', 'strip', 'disc')
DISTINCT_MM = 2.0      # a half turn moving a feature by less than this counts as a symmetry
_TRIES = 200


def _slot(x0, y0, x1, y1, radius) -> Sdf:
    """A slot through everything along z: the segment (x0, y0)-(x1, y1) widened by radius."""
    a, d = np.array([x0, y0], float), np.array([x1 - x0, y1 - y0], float)

    def sdf(x, y, z):
        t = np.clip(((x - a[0]) * d[0] + (y - a[1]) * d[1]) / max(d @ d, 1e-9), 0.0, 1.0)
        return np.hypot(x - a[0] - t * d[0], y - a[1] - t * d[1]) - radius
    return sdf


def _cuts_xy(cuts, axis: int = 2, offset=(0.0, 0.0, 0.0)) -> list[Sdf]:
    """Holes ``(u, v, r)`` and slots ``(u0, v0, u1, v1, r)`` through everything along z."""
    out: list[Sdf] = []
    for c in cuts:
        if len(c) == 3:
            centre = [c[0], c[1], 0.0]
            out.append(cylinder_sdf(tuple(np.add(centre, offset)), c[2], 200.0, axis))
        else:
            out.append(_slot(*c))
    return out


def shape(spec: dict) -> tuple[Sdf, tuple[np.ndarray, np.ndarray]]:
    """(signed distance function in mm, (low, high) bounds in mm) of one drawn part."""
    kind = spec['kind']
    if kind in ('plate', 'strip'):
        L, W, t = spec['length'], spec['width'], spec['thickness']
        solid = box_sdf((0, 0, t / 2), (L / 2, W / 2, t / 2), chamfer=spec['chamfer'])
        return minus_sdf(solid, *_cuts_xy(spec['cuts'])), _bounds((L, W, t), (0, 0, t / 2))
    if kind == 'bracket':
        a, b, w, t = spec['leg_a'], spec['leg_b'], spec['width'], spec['thickness']
        sdf = bracket_sdf(a, b, w, t, [], [])
        base = _cuts_xy(spec['cuts_a'])
        wall = [cylinder_sdf((0, y, z), r, 200.0, axis=0) for y, z, r in spec['cuts_b']]
        return minus_sdf(sdf, *base, *wall), _bounds((a, w, b), (a / 2, 0, b / 2))
    if kind == 'block':
        L, W, H = spec['length'], spec['width'], spec['height']
        solid = box_sdf((0, 0, H / 2), (L / 2, W / 2, H / 2), chamfer=spec['chamfer'])
        cross = [cylinder_sdf((0, y, z), r, 200.0, axis=0) for y, z, r in spec['cross']]
        return minus_sdf(solid, *_cuts_xy(spec['cuts']), *cross), _bounds((L, W, H), (0, 0, H / 2))
    if kind == 'disc':
        R, t, n, rc = spec['radius'], spec['thickness'], spec['holes'], spec['circle']
        angles = 2 * np.pi * np.arange(n) / n
        ring = [(rc * np.cos(a), rc * np.sin(a), spec['hole_radius']) for a in angles]
        sdf = minus_sdf(cylinder_sdf((0, 0, t / 2), R, t / 2),
                     *_cuts_xy([(0.0, 0.0, spec['bore'])] + ring))
        return sdf, _bounds((2 * R, 2 * R, t), (0, 0, t / 2))
    if kind == 'tube':
        L, ro, ri = spec['length'], spec['outer'], spec['inner']
        sdf = minus_sdf(cylinder_sdf((0, 0, 0), ro, L / 2, axis=0),
                     cylinder_sdf((0, 0, 0), ri, L / 2 + 5, axis=0))
        return sdf, _bounds((L, 2 * ro, 2 * ro), (0, 0, 0))
    raise ValueError(f'unknown kind {kind!r}')


def _bounds(size, centre) -> tuple[np.ndarray, np.ndarray]:
    half = np.asarray(size, float) / 2 + 1.0
    return np.asarray(centre, float) - half, np.asarray(centre, float) + half


def symmetries(spec: dict) -> dict:
    """The BOP models_info entry of the part's symmetries (mm): a disc's n holes on a circle
    (n turns about its axis, n flips), a tube's axis and end for end; none for the others."""
    if spec['kind'] == 'disc':
        n, centre = spec['holes'], (0.0, 0.0, spec['thickness'] / 2)
        listed = [bop_rotation((0, 0, 1), 360.0 * k / n, centre) for k in range(1, n)]
        listed += [bop_rotation((np.cos(a), np.sin(a), 0), 180, centre)
                   for a in np.pi * np.arange(n) / n]
        return {'symmetries_discrete': listed}
    if spec['kind'] == 'tube':
        return {'symmetries_continuous': [{'axis': [1, 0, 0], 'offset': [0, 0, 0]}],
                'symmetries_discrete': [bop_rotation((0, 0, 1), 180)]}
    return {'symmetries_discrete': []}


def box_turns(spec: dict) -> list[np.ndarray]:
    """The 23 turns (4x4, mm) that map a cube onto itself (quarter, half and diagonal half
    turns, thirds about a diagonal), about the part's bounding box centre: the candidate
    symmetries a box-like part must not have (a nearly square outline makes a quarter or a
    diagonal half turn one)."""
    from itertools import permutations, product

    low, high = shape(spec)[1]
    centre = (low + high) / 2
    turns = []
    for order in permutations(range(3)):
        for signs in product((1.0, -1.0), repeat=3):
            R = np.zeros((3, 3))
            R[range(3), order] = signs
            if np.linalg.det(R) > 0 and not np.allclose(R, np.eye(3)):
                T = np.eye(4)
                T[:3, :3], T[:3, 3] = R, centre - R @ centre
                turns.append(T)
    return turns


def largest_change(sdf_a: Sdf, sdf_b: Sdf, bounds, T=None, *, step_mm: float = 0.5) -> float:
    """Max |sdf_a(p) - sdf_b(T p)| (mm) over a grid in ``bounds``, the distances capped at
    4 mm (far from both surfaces nothing is compared): 0 when T maps a onto b."""
    low, high = bounds
    axes = [np.arange(lo, hi, step_mm) + 0.13 for lo, hi in zip(low, high)]
    p = np.stack(np.meshgrid(*axes, indexing='ij'), -1).reshape(-1, 3)
    q = p if T is None else p @ T[:3, :3].T + T[:3, 3]
    a, b = np.clip(sdf_a(*p.T), -4, 4), np.clip(sdf_b(*q.T), -4, 4)
    return float(np.abs(a - b).max())


def _layout(rng, extent, count, radii, *, chamfer=0.0, slot=False):
    """``count`` holes (u, v, r) inside the rectangle ``extent`` (u0, u1, v0, v1; a chamfer
    keeps them off the corners), 3 mm of material between two round holes (2.5 mm or more
    beside a slot's middle), the first a slot (u0, v0, u1, v1, r) if ``slot``; None if they
    do not fit."""
    u0, u1, v0, v1 = extent
    placed: list[tuple] = []
    discs: list[tuple] = []
    for i in range(count):
        for _ in range(60):
            r = float(rng.uniform(*radii))
            u, v = rng.uniform(u0 + r + 2.5, u1 - r - 2.5), rng.uniform(v0 + r + 2.5, v1 - r - 2.5)
            ends = _slot_ends(rng, u, v) if slot and i == 0 else [(u, v)]
            samples = [np.add(ends[0], np.subtract(ends[-1], ends[0]) * s) for s in (0, .5, 1)]
            if not all(_inside(s, r, extent, chamfer) for s in samples):
                continue
            if all(np.hypot(*(s - np.asarray(d[:2]))) >= r + d[2] + 3.0
                   for s in samples for d in discs):
                break
        else:
            return None
        discs += [(float(s[0]), float(s[1]), r) for s in samples]
        placed.append(tuple(round(float(x), 2) for x in (*ends[0], *ends[-1], r))
                      if len(ends) == 2 else (round(float(u), 2), round(float(v), 2), round(r, 2)))
    return placed


def _slot_ends(rng, u: float, v: float) -> list[tuple]:
    """The ends of a slot centred on (u, v): 6 to 12 mm along u or 4 to 8 mm along v."""
    if rng.random() < 0.5:
        du, dv = rng.uniform(6, 12), 0.0
    else:
        du, dv = 0.0, rng.uniform(4, 8)
    return [(u - du / 2, v - dv / 2), (u + du / 2, v + dv / 2)]


def _inside(point, r, extent, chamfer) -> bool:
    """Whether a hole of radius r at ``point`` keeps 2.5 mm of material to the rectangle's
    edges and to its corners cut by ``chamfer``."""
    u0, u1, v0, v1 = extent
    u, v = point
    if not (u0 + r + 2.5 <= u <= u1 - r - 2.5 and v0 + r + 2.5 <= v <= v1 - r - 2.5):
        return False
    cu, cv, hu, hv = (u0 + u1) / 2, (v0 + v1) / 2, (u1 - u0) / 2, (v1 - v0) / 2
    return abs(u - cu) + abs(v - cv) <= hu + hv - chamfer - (r + 2.5) * np.sqrt(2)


def _r(x: float) -> float:
    return round(float(x), 2)


def _draw_flat(rng, kind: str) -> dict | None:
    if kind == 'plate':
        L, W, n = rng.uniform(45, 85), rng.uniform(28, 50), int(rng.integers(3, 5))
        radii = (1.8, 3.2)
    else:
        L, W, n = rng.uniform(60, 100), rng.uniform(12, 20), int(rng.integers(2, 4))
        radii = (1.6, 2.4)
    chamfer = 0.0 if rng.random() < 0.25 else rng.uniform(1.5, min(6.0, W / 4))
    cuts = _layout(rng, (-L / 2, L / 2, -W / 2, W / 2), n, radii, chamfer=chamfer,
                   slot=rng.random() < 0.5)
    if cuts is None:
        return None
    return {'kind': kind, 'length': _r(L), 'width': _r(W), 'thickness': _r(rng.uniform(3, 6)),
            'chamfer': _r(chamfer), 'cuts': cuts}


def _draw_bracket(rng) -> dict | None:
    a, b, w, t = rng.uniform(35, 60), rng.uniform(22, 40), rng.uniform(20, 32), rng.uniform(4, 6)
    cuts_a = _layout(rng, (t, a, -w / 2, w / 2), int(rng.integers(1, 3)), (1.8, 3.0))
    cuts_b = _layout(rng, (-w / 2, w / 2, t, b), int(rng.integers(1, 3)), (1.8, 3.0))
    if cuts_a is None or cuts_b is None:
        return None
    spec = {'kind': 'bracket', 'leg_a': _r(a), 'leg_b': _r(b), 'width': _r(w),
            'thickness': _r(t), 'cuts_a': cuts_a, 'cuts_b': cuts_b}
    # its mirror image must be another part: the holes not symmetric about y = 0
    return spec if largest_change(*_pair(spec, mirrored(spec))) > DISTINCT_MM else None


def _draw_block(rng) -> dict | None:
    L, W, H = rng.uniform(30, 50), rng.uniform(20, 35), rng.uniform(12, 25)
    chamfer = 0.0 if rng.random() < 0.3 else rng.uniform(1.5, 4.0)
    cuts = _layout(rng, (-L / 2, L / 2, -W / 2, W / 2), int(rng.integers(1, 4)), (2.0, 3.5),
                   chamfer=chamfer)
    cross = _layout(rng, (-W / 2, W / 2, 0, H), 1, (2.0, 3.0)) if rng.random() < 0.6 else []
    if cuts is None or cross is None:
        return None
    return {'kind': 'block', 'length': _r(L), 'width': _r(W), 'height': _r(H),
            'chamfer': _r(chamfer), 'cuts': cuts, 'cross': cross}


def _draw_disc(rng) -> dict:
    R = rng.uniform(15, 28)
    bore = rng.uniform(3, R / 3)
    hole = rng.uniform(1.8, 2.6)
    circle = rng.uniform(bore + hole + 3.5, R - hole - 3.0)
    return {'kind': 'disc', 'radius': _r(R), 'thickness': _r(rng.uniform(3, 6)),
            'bore': _r(bore), 'holes': int(rng.integers(3, 7)), 'circle': _r(circle),
            'hole_radius': _r(hole)}


def _draw_tube(rng) -> dict:
    outer = rng.uniform(6, 14)
    return {'kind': 'tube', 'length': _r(rng.uniform(30, 70)), 'outer': _r(outer),
            'inner': _r(outer - rng.uniform(1.5, 4.0))}


def draw(rng: np.random.Generator, kind: str) -> dict:
    """One part of ``kind`` drawn from ``rng``: no turn of its box maps a box-like part onto
    itself (redrawn until none does)."""
    for _ in range(_TRIES):
        if kind in ('plate', 'strip'):
            spec = _draw_flat(rng, kind)
        elif kind == 'bracket':
            spec = _draw_bracket(rng)
        elif kind == 'block':
            spec = _draw_block(rng)
        else:
            return _draw_disc(rng) if kind == 'disc' else _draw_tube(rng)
        if spec is not None and (kind == 'bracket' or not _symmetric(spec)):
            return spec
    raise RuntimeError(f'no {kind} drawn in {_TRIES} tries')


def _symmetric(spec: dict) -> bool:
    sdf, bounds = shape(spec)
    return any(largest_change(sdf, sdf, bounds, T, step_mm=1.0) <= DISTINCT_MM
               for T in box_turns(spec))


def _pair(a: dict, b: dict):
    (sdf_a, bounds), (sdf_b, _) = shape(a), shape(b)
    return sdf_a, sdf_b, bounds


def mirrored(spec: dict) -> dict:
    """A bracket's mirror image (y -> -y): the same outline, the holes on the other side."""
    return {**spec, 'cuts_a': [(u, -v, r) for u, v, r in spec['cuts_a']],
            'cuts_b': [(-y, z, r) for y, z, r in spec['cuts_b']]}


def _one_hole_less(rng, spec: dict) -> dict:
    """The twin of a plate with one of its round holes left out, still without symmetry."""
    for _ in range(_TRIES):
        cuts = list(spec['cuts'])
        round_holes = [i for i, c in enumerate(cuts) if len(c) == 3]
        cuts.pop(round_holes[int(rng.integers(len(round_holes)))])
        twin = {**spec, 'cuts': cuts}
        if not _symmetric(twin):
            return twin
    raise RuntimeError('no twin without symmetry')


def family(seed: int, count: int = 8) -> dict[str, dict]:
    """``count`` parts drawn from ``seed``, name -> spec: first a plate and its twin with one
    hole less, then a bracket and its mirror image (count >= 4), then the kinds in a random
    order, those not yet drawn first. Names are ``<kind>_<seed><letter>``: valid ROS names."""
    if not 1 <= count <= 26:
        raise ValueError(f'count must be 1 to 26, got {count}')
    rng = np.random.default_rng(seed)
    specs: list[dict] = []
    if count >= 2:
        plate = draw(rng, 'plate')
        while sum(len(c) == 3 for c in plate['cuts']) < 2:
            plate = draw(rng, 'plate')
        specs += [plate, {**_one_hole_less(rng, plate), 'twin_of': 0}]
    if count >= 4:
        bracket = draw(rng, 'bracket')
        specs += [bracket, {**mirrored(bracket), 'mirror_of': 2}]
    paired = {s['kind'] for s in specs}
    order = [KINDS[i] for i in rng.permutation(len(KINDS))]
    order = [k for k in order if k not in paired] + [k for k in order if k in paired]
    first = len(specs)
    while len(specs) < count:
        specs.append(draw(rng, order[(len(specs) - first) % len(order)]))
    names = [f"{s['kind']}_{seed}{chr(ord('a') + i)}" for i, s in enumerate(specs)]
    return {name: _named(s, names) for name, s in zip(names, specs)}


def _named(spec: dict, names: list[str]) -> dict:
    """The spec with its look-alike's index replaced by the look-alike's name, as plain JSON
    values (lists)."""
    out = json.loads(json.dumps(spec))
    for key in ('twin_of', 'mirror_of'):
        if key in out:
            out[key] = names[out[key]]
    return out


def generate_family(out: str | Path, seed: int, count: int = 8,
                    names: list[str] | None = None) -> list[Path]:
    """Write the family drawn from ``seed`` (all ``count`` parts, or ``names``) as
    :func:`~.part_generator.generate_parts` writes parts, and each part's spec as
    ``<out>/family.json``; the STL paths."""
    specs = family(seed, count)
    paths = generate_parts(out, names, shapes={n: shape(s) for n, s in specs.items()},
                           symmetries={n: symmetries(s) for n, s in specs.items()})
    (Path(out) / 'family.json').write_text(json.dumps(
        {'seed': seed, 'count': count, 'parts': specs}, indent=1) + '\n')
    return paths
