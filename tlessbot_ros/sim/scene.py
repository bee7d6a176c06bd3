"""Random table scenes: parts of random classes in stable poses, visible to every camera.

Placement is sequential rejection sampling. Each part gets a resting pose drawn with its
probability (:func:`~tlessbot_ros.io.models.stable_poses`), a uniform yaw and a position in the
work area, either anywhere or (with ``cluster_prob``) right next to an already placed part, so
that crowded, touching and occluding arrangements like the paper's test scenes are common.
With ``lean_prob`` a part may instead lean: its resting pose is tilted by ``lean_deg`` about a
random horizontal axis and lowered onto the table, as a part propped against a neighbour would
be (contact with the neighbour is not enforced; such a part is in no stable pose, which is what
the pose stage's fallback is for). Candidates are rejected when their convex hulls
interpenetrate by more than ``touch_tol_m``
(conservative for concave parts: they never nest into each other) or when any hull vertex would
fall outside an image (``margin_px``).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlessbot_ros.core.common import (
    Rig,
    project_points,
    rotation_about_axis,
    sample_surface,
    transform_points,
)
from tlessbot_ros.io.models import ObjectModel, stable_poses


@dataclass
class PlacedObject:
    """A part in the scene: its class and ``T_world_object`` (4x4, metres; world = table)."""

    obj_id: int
    T_world_object: np.ndarray
    material: str = ''


@dataclass(frozen=True)
class SceneParams:
    """Scene sampling options (see the module docstring; ``lean_prob`` 0 draws no extra random
    numbers, so scenes stay as they were without it)."""

    parts_min: int = 1
    parts_max: int = 8
    area_radius_m: float = 0.2
    cluster_prob: float = 0.5
    unique_classes: bool = True
    margin_px: int = 8
    touch_tol_m: float = 0.0005
    max_tries: int = 80
    hull_samples: int = 200
    lean_prob: float = 0.0
    lean_deg: tuple[float, float] = (15.0, 40.0)


@dataclass
class HullInfo:
    equations: np.ndarray  # (F, 4): n . x + d <= 0 inside, model frame
    samples: np.ndarray  # (S, 3) points on the hull surface, model frame
    vertices: np.ndarray  # (H, 3) hull vertices, model frame
    radius: float  # bounding sphere radius about the model origin


def hull_info(model: ObjectModel, samples: int) -> HullInfo:
    def build() -> HullInfo:
        from scipy.spatial import ConvexHull

        hull = ConvexHull(model.vertices)
        # seeded by the model id: placement stays reproducible
        pts, _ = sample_surface(hull.points, hull.simplices, samples, seed=model.obj_id,
                                scheme='sqrt')
        verts = hull.points[hull.vertices]
        # Coplanar hull triangles share a plane: keep each plane once.
        eq = np.unique(np.round(hull.equations, 9), axis=0)
        return HullInfo(eq, np.vstack([verts, pts]), verts,
                         float(np.linalg.norm(verts, axis=1).max()))
    return model.cached(('hull_info', samples), build)


def _penetrates(a: HullInfo, T_a: np.ndarray, b: HullInfo, T_b: np.ndarray,
                tol: float) -> bool:
    """Do the two placed hulls overlap deeper than ``tol`` (surface samples inside the other)?"""
    if np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) > a.radius + b.radius:
        return False
    T_b_a = np.linalg.solve(T_b, T_a)
    return (_inside(transform_points(T_b_a, a.samples), b, tol)
            or _inside(transform_points(np.linalg.inv(T_b_a), b.samples), a, tol))


def _inside(pts: np.ndarray, hull: HullInfo, tol: float) -> bool:
    """Is any of the (N, 3) points deeper than ``tol`` inside the hull (its own frame)?"""
    lo, hi = hull.vertices.min(axis=0) + tol, hull.vertices.max(axis=0) - tol
    pts = pts[np.all((pts > lo) & (pts < hi), axis=1)]
    if len(pts) == 0:
        return False
    return bool(np.any(np.all(pts @ hull.equations[:, :3].T + hull.equations[:, 3] < -tol,
                              axis=1)))


def _in_views(info: HullInfo, T_world_object: np.ndarray, rig: Rig, margin_px: int) -> bool:
    pts_w = transform_points(T_world_object, info.vertices)
    for cam in rig.cameras.values():
        pts_c = transform_points(cam.T_camera_world, pts_w)
        if np.any(pts_c[:, 2] < 0.1):
            return False
        uv = project_points(pts_c, cam.intrinsics.K)
        w, h = cam.intrinsics.width, cam.intrinsics.height
        if (uv.min() < margin_px or np.any(uv[:, 0] > w - 1 - margin_px)
                or np.any(uv[:, 1] > h - 1 - margin_px)):
            return False
    return True


def _lean(T_world_object: np.ndarray, info: HullInfo, rng: np.random.Generator,
          angle_deg: tuple[float, float]) -> np.ndarray:
    """The pose tilted by an angle in ``angle_deg`` about a random horizontal axis through its
    origin, then lowered so that its lowest hull vertex touches the table (z = 0)."""
    azimuth = rng.uniform(-np.pi, np.pi)
    tilt = np.radians(rng.uniform(*angle_deg))
    axis = np.array([np.cos(azimuth), np.sin(azimuth), 0.0])
    T = np.eye(4)
    T[:3, :3] = rotation_about_axis(axis, tilt) @ T_world_object[:3, :3]
    T[:3, 3] = T_world_object[:3, 3]
    T[2, 3] -= transform_points(T, info.vertices)[:, 2].min()
    return T


def placement_fits(info: HullInfo, T_world_object: np.ndarray, rig: Rig,
                   others: list[tuple[HullInfo, np.ndarray]], *, margin_px: int,
                   touch_tol_m: float) -> bool:
    """Whether a part (its hull ``info`` at ``T_world_object``) is seen whole by every camera of
    ``rig`` and penetrates none of ``others`` ((hull, T_world_object) each)."""
    return _in_views(info, T_world_object, rig, margin_px) and not any(
        _penetrates(info, T_world_object, hull, T, touch_tol_m) for hull, T in others)


def work_area_centre(rig: Rig) -> np.ndarray:
    """(2,) table point at the middle of what all cameras see (mean of the optical axes' hits)."""
    hits = []
    for cam in rig.cameras.values():
        T = cam.T_world_camera
        axis, origin = T[:3, 2], T[:3, 3]
        if axis[2] < -1e-6:
            hits.append((origin - origin[2] / axis[2] * axis)[:2])
    return np.mean(hits, axis=0) if hits else np.zeros(2)


def sample_scene(models: dict[int, ObjectModel], rig: Rig, rng: np.random.Generator,
                 params: SceneParams = SceneParams(), *,
                 materials: tuple[str, ...] = ('',)) -> list[PlacedObject]:
    """Draw one scene of ``parts_min..parts_max`` parts (fewer if the area is too crowded).

    Returns:
        placed parts, each with ``T_world_object`` resting on z = 0 and a material name drawn
        from ``materials``.
    """
    if not models:
        raise ValueError('no models to place')
    if not 0 <= params.parts_min <= params.parts_max:
        raise ValueError(f'need 0 <= parts_min <= parts_max, got {params.parts_min}, '
                         f'{params.parts_max}')
    ids = sorted(models)
    count = int(rng.integers(params.parts_min, params.parts_max + 1))
    if params.unique_classes:
        classes = list(rng.permutation(ids)[:count]) if count <= len(ids) else \
            list(rng.permutation(ids)) + list(rng.choice(ids, count - len(ids)))
    else:
        classes = list(rng.choice(ids, count))
    centre = work_area_centre(rig)
    placed: list[PlacedObject] = []
    infos: list[HullInfo] = []
    for obj_id in classes:
        model = models[int(obj_id)]
        info = hull_info(model, params.hull_samples)
        poses = stable_poses(model)
        probs = np.array([p.probability for p in poses])
        material = str(materials[int(rng.integers(len(materials)))])
        for _ in range(params.max_tries):
            rest = poses[int(rng.choice(len(poses), p=probs / probs.sum()))].T_table_object
            yaw = rng.uniform(-np.pi, np.pi)
            c, s = np.cos(yaw), np.sin(yaw)
            T = np.eye(4)
            T[:2, :2] = [[c, -s], [s, c]]
            T = T @ rest
            if params.lean_prob > 0 and rng.random() < params.lean_prob:
                T = _lean(T, info, rng, params.lean_deg)
            if placed and rng.random() < params.cluster_prob:
                k = int(rng.integers(len(placed)))
                angle = rng.uniform(-np.pi, np.pi)
                dist = (info.radius + infos[k].radius) * rng.uniform(0.45, 1.0)
                xy = placed[k].T_world_object[:2, 3] + dist * np.array([np.cos(angle),
                                                                         np.sin(angle)])
            else:
                r = params.area_radius_m * np.sqrt(rng.random())
                angle = rng.uniform(-np.pi, np.pi)
                xy = centre + r * np.array([np.cos(angle), np.sin(angle)])
            if np.linalg.norm(xy - centre) > params.area_radius_m:
                continue
            T[:2, 3] += xy
            if not _in_views(info, T, rig, params.margin_px):
                continue
            if any(_penetrates(info, T, other, p.T_world_object, params.touch_tol_m)
                   for other, p in zip(infos, placed)):
                continue
            placed.append(PlacedObject(int(obj_id), T, material))
            infos.append(info)
            break
    return placed
