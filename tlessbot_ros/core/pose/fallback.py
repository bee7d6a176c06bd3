"""The bounded fallback of the pose stage: a 6-DOF search for parts the table path cannot fit.

A part leaning on another, or a view without a table frame (no extrinsics, no plane found):
the table path's hypotheses (a stable pose, a yaw, a position on the plane) cannot describe
it, so the pose is searched in all six degrees of freedom. The paper's answer, FPFH + RANSAC
against each of 12 templates (:mod:`~tlessbot_ros.core.pose.ransac`), costs 1-3 s per part
and often ends a half-turn off: on textureless T-LESS parts the nearest FPFH match is right
for a few % of the ROI points (docs/bench/fallback.md), so RANSAC needs 10^5 draws. This
search does a fixed, small amount of work instead, coarse to fine:

0. **Clutter.** Up to ``fallback_drop_planes`` RANSAC planes wider than the part
   (``fallback_plane_width`` diameters) leave the ROI: the table that a box ROI holds
   would drag every view's centroid off the part. With a table frame the first of them is
   the table itself, not searched: the points within ``fallback_table_band`` plane
   distances of it, or below it, when they spread wider than the part (RANSAC may settle on
   a near-equal plane beside the table's, one that cuts a face of the part or leaves a strip
   of table, and the part's pose turns on which).
1. **A grid of views, scored at once.** The object's rotations are sampled as a camera sees
   them: ``fallback_directions`` viewing directions spread evenly over the sphere (a
   Fibonacci lattice) times ``fallback_in_plane_steps`` turns about the line of sight. Each
   view puts the centroid of the surface it shows (self-occlusion included, computed once per
   object) on the centroid of the ROI, seen along the same ray. Rotations that the object's
   exact symmetries make equal are kept once. Every view is scored in one pass on the
   object's nearest-sample grid (truncated mean distance of ``fallback_coarse_points`` points
   of the ROI voxelised ``fallback_voxel_scale`` times coarser than the templates), the best
   ``fallback_keep`` again on ``score_points`` points, and the best ``fallback_icp_starts``
   get a few point-to-plane ICP steps at the coarse voxel.
2. **Fine refinement against the full model, symmetry-aware.** The best ``fallback_refine``
   distinct coarse poses (plus any given starts, e.g. the table path's best) are refined by
   point-to-plane ICP at the template voxel (:meth:`~tlessbot_ros.core.pose.Refiner.icp_batch`);
   the best ``fallback_turned`` are turned by each of the object's near-symmetries (turns
   about its axes that map the surface almost, but not exactly, onto itself: the turn that
   loses RANSAC the rotation) and refined again; the best ``final_candidates`` by grid
   fitness, told apart modulo the exact symmetries, get ``fallback_fine_iterations`` last ICP
   steps with every ROI point and are scored fully
   (:meth:`~tlessbot_ros.core.pose.Refiner.evaluate`: tangent-plane fitness and coverage).

The work is bounded by construction: the numbers of views, points, refined starts and
scored candidates are fixed settings, and no loop runs until a confidence is reached.
``fallback_budget_ms`` is an opt-in wall-time cap (0, the default, is none, so that a result
does not depend on the host's speed): once spent, the near-symmetry turns are skipped.

Poses are ``T_camera_object`` (4, 4) float64, metres, in the ROI cloud's camera frame.

References:
    Á. González, "Measurement of areas on a sphere using Fibonacci and latitude-longitude
    lattices", Mathematical Geosciences 42, 2010 (the Fibonacci lattice).
    Y. Chen, G. Medioni, "Object modelling by registration of multiple range images",
    Image and Vision Computing 10(3), 1992 (point-to-plane ICP).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy.spatial import cKDTree

from tlessbot_ros.core.common import rotation_about_axis
from tlessbot_ros.core.pose.candidates import PoseCandidate, poses_differ
from tlessbot_ros.core.pose.cloud import fit_plane, voxel_downsample
from tlessbot_ros.core.pose.database import ObjectTemplates
from tlessbot_ros.core.pose.grid_kernels import self_visible
from tlessbot_ros.core.pose.params import PoseParams
from tlessbot_ros.core.pose.refinement import Refiner

# The canonical camera looks along +z at an object on its optical axis this far away.
_CANONICAL_DISTANCE_M = 0.6


@dataclass(frozen=True)
class NearSymmetries:
    """Turns of an object about axes through its surface centroid, by how well they map the
    surface onto itself.

    Attributes:
        turns: (K, 4, 4) float64 object-frame transforms ``S`` that are near-symmetries
            (``T @ S`` may fit a view almost as well as ``T``): tried from every refined pose.
        exact: (E, 4, 4) float64 object-frame transforms that are symmetries within a
            fraction of a voxel, identity first: ``T`` and ``T @ S`` are the same pose.
    """

    turns: np.ndarray
    exact: np.ndarray


@dataclass(frozen=True)
class ViewGrid:
    """The object's rotations as views of a canonical camera (see the module docstring).

    Attributes:
        rotations: (V, 3, 3) float64 ``R_canonical_object`` of each view; the canonical camera
            looks along +z at the object, whose origin lies on its optical axis.
        visible_centroids: (V, 3) float64 centroid of the surface that view shows, relative
            to the object origin, in the canonical camera frame (metres).
    """

    rotations: np.ndarray
    visible_centroids: np.ndarray


def fibonacci_sphere(count: int) -> np.ndarray:
    """(count, 3) unit vectors spread evenly over the sphere (a spherical Fibonacci
    lattice: equal-area bands, golden-angle longitudes)."""
    if count < 1:
        raise ValueError(f'count must be >= 1, got {count}')
    i = np.arange(count) + 0.5
    polar = np.arccos(1.0 - 2.0 * i / count)
    azimuth = np.pi * (1.0 + 5.0 ** 0.5) * i
    return np.stack([np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar),
                     np.cos(polar)], axis=1)


def rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation taking direction ``a`` to direction ``b``: (3, 3) for (3,) ``a``,
    (N, 3, 3) for (N, 3) ``a``; opposite directions get a half-turn about an axis
    perpendicular to ``b``."""
    a = np.asarray(a, np.float64)
    single = a.ndim == 1
    a = np.atleast_2d(a) / np.linalg.norm(np.atleast_2d(a), axis=1, keepdims=True)
    b = np.asarray(b, np.float64) / np.linalg.norm(b)
    axis = np.cross(a, b)
    sin, cos = np.linalg.norm(axis, axis=1), a @ b
    parallel = sin < 1e-12
    axis[parallel] = np.cross(b, np.eye(3)[int(np.argmin(np.abs(b)))])
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    angle = np.where(parallel, np.where(cos < 0, np.pi, 0.0), np.arctan2(sin, cos))
    K = np.zeros((len(a), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -axis[:, 2], axis[:, 1], -axis[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = axis[:, 2], -axis[:, 1], axis[:, 0]
    angle = angle[:, None, None]
    R = np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)
    return R[0] if single else R


def turn_axes(points: np.ndarray) -> list[np.ndarray]:
    """The axes a part's (near-)symmetries are looked for about: the model frame's axes, then
    the principal axes of its (N, 3) surface samples that are not within 5° of one of them
    (unit vectors)."""
    centre = points.mean(axis=0)
    _, principal = np.linalg.eigh(np.cov((points - centre).T))
    axes: list[np.ndarray] = []
    for axis in [*np.eye(3), *principal.T]:
        if all(abs(axis @ a) < np.cos(np.radians(5.0)) for a in axes):
            axes.append(axis / np.linalg.norm(axis))
    return axes


def near_symmetries(obj: ObjectTemplates, *, exact_ratio: float = 1.35,
                    near_ratio: float = 2.5) -> NearSymmetries:
    """The object's near and exact symmetries among turns about its axes (built once per
    object and kept).

    Candidates: turns by multiples of 45° about the object frame's axes and the surface's
    principal axes, through the surface centroid. A turn is judged by the median distance of
    the turned surface samples to the nearest sample, in units of the median distance between
    neighbouring samples (1 for a perfect symmetry, given the sampling): up to ``exact_ratio``
    it is a symmetry; a turn by 90°, 180° or 270° up to ``near_ratio`` is a near-symmetry. The
    half-turns about the object axes are near-symmetries whatever their ratio (as the table
    path's ``flip_axes``): a view shows only part of the surface, and a turn that does not fit
    the whole surface may still fit that part. On the 23 shipped parts the ratio is 1.0-1.3
    for their listed symmetries and 1.4-9 for the other turns, but for obj_25's half-turn
    about z (1.2, not listed in its models_info.json).
    """
    key = ('fallback_symmetries', float(exact_ratio), float(near_ratio))
    if key in obj._cache:
        return cast(NearSymmetries, obj._cache[key])
    model = obj.model_points.astype(np.float64)
    tree = obj.model_tree()
    sub = model[::max(1, len(model) // 600)]
    spacing = float(np.median(tree.query(sub, k=2)[0][:, 1]))   # [:, 0] is the sample itself
    centre = model.mean(axis=0)
    axes = turn_axes(model)
    exact, near = [np.eye(4)], []
    for i, axis in enumerate(axes):
        for eighth in range(1, 8):
            S = np.eye(4)
            S[:3, :3] = rotation_about_axis(axis, eighth * np.pi / 4.0)
            S[:3, 3] = centre - S[:3, :3] @ centre
            ratio = float(np.median(tree.query(sub @ S[:3, :3].T + S[:3, 3])[0])) / spacing
            if ratio <= exact_ratio:
                exact.append(S)
            elif eighth % 2 == 0 and (ratio <= near_ratio or (i < 3 and eighth == 4)):
                near.append(S)
    result = NearSymmetries(np.array(near).reshape(-1, 4, 4), np.array(exact))
    obj._cache[key] = result
    return result


def view_grid(obj: ObjectTemplates, *, directions: int, in_plane_steps: int) -> ViewGrid:
    """The object's :class:`ViewGrid` (built once per setting and kept: 0.1-0.3 s).

    Views that an exact symmetry of :func:`near_symmetries` maps onto an earlier view (within
    half the grid's angular step) are dropped: a part with a continuous axis keeps about an
    eighth of them.
    """
    key = ('fallback_views', int(directions), int(in_plane_steps))
    if key in obj._cache:
        return cast(ViewGrid, obj._cache[key])
    # 1000 of the surface samples (random order) place a centroid well within a voxel; the
    # z-buffer's cells are a voxel wide so that they hold a front sample each.
    model, normals = obj.model_subset(1000)
    toward_camera = np.array([0.0, 0.0, -1.0])
    cell = obj.voxel_size_m / _CANONICAL_DISTANCE_M
    R0 = rotation_between(fibonacci_sphere(directions), toward_camera)
    centroids = np.empty((directions, 3))
    for k, R in enumerate(R0):   # the surface each direction shows, self-occlusion included
        seen = self_visible(model @ R.T + [0.0, 0.0, _CANONICAL_DISTANCE_M], normals @ R.T,
                            cell, obj.voxel_size_m)
        centroids[k] = model[seen].mean(axis=0) if seen.any() else model.mean(axis=0)
    spins = np.array([rotation_about_axis(toward_camera, a)
                      for a in 2.0 * np.pi * np.arange(in_plane_steps) / in_plane_steps])
    R_all = (spins[None] @ R0[:, None]).reshape(-1, 3, 3)              # (D * P, 3, 3)
    c_all = np.einsum('kij,kj->ki', R_all, np.repeat(centroids, in_plane_steps, axis=0))
    keep = _unique_modulo(R_all, near_symmetries(obj).exact[:, :3, :3],
                          tolerance_rad=0.5 * np.sqrt(4.0 * np.pi / directions))
    grid = ViewGrid(R_all[keep], c_all[keep])
    obj._cache[key] = grid
    return grid


def _unique_modulo(R: np.ndarray, symmetries: np.ndarray, *, tolerance_rad: float
                   ) -> np.ndarray:
    """Indices of the rotations (V, 3, 3) to keep: the first of each set that the
    ``symmetries`` (E, 3, 3) map onto each other within ``tolerance_rad``."""
    if len(symmetries) < 2:
        return np.arange(len(R))
    tree = cKDTree(R.reshape(len(R), 9))
    # ||R_a - R_b||_F = 2 sqrt(2) sin(angle / 2)
    radius = 2.0 * np.sqrt(2.0) * np.sin(0.5 * tolerance_rad)
    # (V, E - 1): the view nearest to each view turned by each symmetry (V where none is near)
    _, same = tree.query((R[:, None] @ symmetries[None, 1:]).reshape(-1, 9),
                         distance_upper_bound=radius)
    same = same.reshape(len(R), len(symmetries) - 1)
    dropped = np.zeros(len(R) + 1, bool)
    for i in range(len(R)):
        if not dropped[i]:
            dropped[same[i][same[i] > i]] = True
    dropped = dropped[:-1]
    return np.flatnonzero(~dropped)


def fallback_candidates(scene_c: np.ndarray, obj: ObjectTemplates, timings: dict[str, float],
                        *, params: PoseParams, refiner: Refiner,
                        starts: np.ndarray | None = None,
                        deadline: float | None = None,
                        T_world_camera: np.ndarray | None = None) -> list[PoseCandidate]:
    """The bounded fallback's candidates for one object (see the module docstring).

    Args:
        scene_c: (S, 3) the ROI voxelised at the template voxel, outliers removed; camera
            frame, metres.
        obj: the object's surface samples and caches.
        timings: gets ``'views'`` (the coarse search) and ``'refine'`` in ms.
        params: the ``fallback_*`` settings (and ``score_points``, ``final_candidates``).
        refiner: ICP and scoring.
        starts: (K, 4, 4) extra ``T_camera_object`` refined with the coarse poses (e.g. the
            table path's best).
        deadline: a ``time.perf_counter()`` value after which the near-symmetry turns are
            skipped.
        T_world_camera: (4, 4) the camera in a world frame whose z = 0 plane is the table,
            when known: the table leaves the ROI by its height (step 0).

    Returns:
        scored candidates (method 'views'), best first; empty when the ROI has fewer than 10
        points.
    """
    scene_c = np.asarray(scene_c, np.float64)
    if len(scene_c) < 10:
        return []
    p = params
    t0 = time.perf_counter()
    if p.fallback_drop_planes:
        scene_c = without_clutter(scene_c, obj, p, T_world_camera)
        if len(scene_c) < 10:
            return []
    T_coarse = _coarse_poses(scene_c, obj, p, refiner)
    t1 = time.perf_counter()
    timings['views'] = 1e3 * (t1 - t0)

    T_start = T_coarse if starts is None or not len(starts) else \
        np.concatenate([T_coarse, np.asarray(starts, np.float64).reshape(-1, 4, 4)])
    refined = refiner.icp_batch(scene_c, obj, T_start)
    symmetries = near_symmetries(obj)
    if len(symmetries.turns) and (deadline is None or time.perf_counter() < deadline):
        # RANSAC's classic miss: a turn that fits the visible side almost as well. Turn the
        # best refined poses by each near-symmetry and refine again.
        fit = refiner.grid_fitness(refined, scene_c, obj)
        best = refined[np.argsort(-fit, kind='stable')[:p.fallback_turned]]
        turned = (best[:, None] @ symmetries.turns[None]).reshape(-1, 4, 4)
        refined = np.concatenate([refined, refiner.icp_batch(scene_c, obj, turned)])
    fit = refiner.grid_fitness(refined, scene_c, obj)
    chosen: list[int] = []
    for k in np.argsort(-fit, kind='stable'):
        if len(chosen) == p.final_candidates:
            break
        if all(_differs_modulo(refined[k], refined[c], symmetries.exact) for c in chosen):
            chosen.append(int(k))
    # The survivors' last ICP steps, with every scene point.
    final = refiner.icp_batch(scene_c, obj, refined[chosen], iterations=p.fallback_fine_iterations,
                              points=len(scene_c))
    out = [refiner.evaluate(scene_c, obj, T, method='views') for T in final]
    timings['refine'] = 1e3 * (time.perf_counter() - t1)
    return sorted(out, key=lambda c: (-c.score, c.inlier_rmse_m))


def without_clutter(scene_c: np.ndarray, obj: ObjectTemplates, p: PoseParams,
                    T_world_camera: np.ndarray | None = None) -> np.ndarray:
    """The (S, 3) camera-frame ROI without the table and up to ``fallback_drop_planes`` wide
    planes in all (step 0 of the module docstring).

    With ``T_world_camera`` (4, 4), the camera in a world frame whose z = 0 plane is the
    table, and ``fallback_table_band`` > 0, the table is the first plane and known: the
    points less than ``fallback_table_band * cloud.plane_distance_m`` above it (those below
    it included: no part is there) leave when they spread wider than
    ``fallback_plane_width`` part diameters, as a searched plane would, and the search looks
    for the others only (a box wall). Without it, every plane is searched
    (:func:`_without_wide_planes`).
    """
    planes = p.fallback_drop_planes
    if T_world_camera is not None and p.fallback_table_band > 0 and planes:
        T = np.asarray(T_world_camera, np.float64)
        near = scene_c @ T[2, :3] + T[2, 3] < p.fallback_table_band * p.cloud.plane_distance_m
        # As a searched plane, the table leaves only where the ROI holds it (wider than the
        # part): the rim of a part seen without the table around it stays.
        if near.sum() >= 3 and _spread(scene_c[near]) > p.fallback_plane_width * obj.diameter_m:
            scene_c = scene_c[~near]
        planes -= 1
    return _without_wide_planes(scene_c, obj, p, planes)


def _without_wide_planes(scene_c: np.ndarray, obj: ObjectTemplates, p: PoseParams,
                         planes: int) -> np.ndarray:
    """The ROI without up to ``planes`` planes wider than ``fallback_plane_width`` times the
    part's diameter: a box ROI without a table frame holds the table around the part, which
    would drag the views' centroids off it, while any two points of the part lie within its
    diameter, so none of its own faces is dropped."""
    for _ in range(planes):
        if len(scene_c) < 20:
            break
        _, inliers = fit_plane(scene_c, distance_m=p.cloud.plane_distance_m,
                               iterations=p.cloud.plane_iterations, seed=p.seed)
        on = scene_c[inliers]
        if len(on) < 3 or _spread(on) <= p.fallback_plane_width * obj.diameter_m:
            break
        scene_c = scene_c[~inliers]
    return scene_c


def _spread(points: np.ndarray) -> float:
    """Largest extent of (N, 3) points along their principal axes (m)."""
    centred = points - points.mean(axis=0)
    _, _, Vt = np.linalg.svd(centred, full_matrices=False)
    along = centred @ Vt[0]
    return float(along.max() - along.min())


def _coarse_poses(scene_c: np.ndarray, obj: ObjectTemplates, p: PoseParams,
                  refiner: Refiner) -> np.ndarray:
    """(H, 4, 4) the best distinct ``T_camera_object`` of the view grid after the coarse
    ICP steps (H <= ``fallback_refine``)."""
    grid = view_grid(obj, directions=p.fallback_directions,
                     in_plane_steps=p.fallback_in_plane_steps)
    coarse, _ = voxel_downsample(scene_c, p.fallback_voxel_scale * obj.voxel_size_m)
    centre = coarse.mean(axis=0)
    # The canonical camera's optical axis turned onto the ray through the ROI centroid.
    Q = rotation_between(np.array([0.0, 0.0, 1.0]), centre)
    T = np.tile(np.eye(4), (len(grid.rotations), 1, 1))
    T[:, :3, :3] = Q @ grid.rotations
    T[:, :3, 3] = centre - grid.visible_centroids @ Q.T
    rng = np.random.default_rng(p.seed)
    tau = 2.0 * obj.voxel_size_m

    def subset(count: int) -> np.ndarray:
        return coarse if len(coarse) <= count else \
            coarse[rng.choice(len(coarse), count, replace=False)]
    cost = refiner.truncated_cost(T, subset(p.fallback_coarse_points), obj, tau=tau)
    keep = np.argsort(cost, kind='stable')[:p.fallback_keep]
    cost = refiner.truncated_cost(T[keep], subset(p.score_points), obj, tau=tau)
    T = T[keep[np.argsort(cost, kind='stable')[:p.fallback_icp_starts]]]
    # The view's position comes from centroids that occlusion shifts by up to a few voxels:
    # a wide correspondence distance first.
    T = refiner.icp_batch(coarse, obj, T, iterations=p.fallback_icp_iterations,
                          distance_m=p.fallback_icp_distance_voxels * obj.voxel_size_m)
    fit = refiner.grid_fitness(T, coarse, obj)
    chosen: list[int] = []
    for k in np.argsort(-fit, kind='stable'):
        if len(chosen) == p.fallback_refine:
            break
        if all(poses_differ(T[k], T[c], r_deg=10.0) for c in chosen):
            chosen.append(int(k))
    return T[chosen]


def _differs_modulo(T_a: np.ndarray, T_b: np.ndarray, exact: np.ndarray) -> bool:
    """True when ``T_a`` differs from every symmetric equivalent ``T_b @ S`` of ``T_b``."""
    return all(poses_differ(T_a, T_b @ S) for S in exact)
