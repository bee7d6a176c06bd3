"""6D pose of a recognised object from its ROI cloud (paper §3.3, §6.2, and a faster path).

Two estimators share one refinement and one scoring:

* ``'ransac'`` – the paper's method, improved: FPFH + sample-consensus initial alignment
  (Open3D RANSAC on feature matches, mutual filter, edge-length and distance checkers) of each
  template of the recognised class against the ROI cloud, then point-to-plane ICP against the
  CAD surface; best and second-best candidates by score after refinement.
* ``'table'`` (default, falls back to ``'ransac'`` when its fit is poor) – parts rest on the
  table, so the pose is one of the part's stable poses turned by a yaw and shifted on the plane.
  For every stable pose and yaw hypothesis (yaw steps pruned by the pose's rotational symmetry)
  the position on the plane is set by matching the centroid of the model surface facing the
  camera to the ROI centroid, every hypothesis is scored at once through a precomputed
  nearest-sample grid of the model, the best few are refined in (yaw, x, y) by point-to-plane
  Gauss-Newton steps on that grid, and the winner gets a full 6-DOF point-to-plane ICP.
  This needs the table frame: ``T_world_camera`` with the table at world z = 0 (the rig's
  extrinsics, or :func:`table_frame_from_plane` of a fitted plane).

Poses are ``T_camera_object`` (4, 4) float64, metres, in the optical frame of the ROI cloud.

References:
    R. B. Rusu, N. Blodow, M. Beetz, "Fast Point Feature Histograms (FPFH) for 3D
    Registration", ICRA 2009 (FPFH, SAC-IA).
    Y. Chen, G. Medioni, "Object modelling by registration of multiple range images",
    Image and Vision Computing 10(3), 1992 (point-to-plane ICP).
"""
from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import open3d as o3d

from tlessbot_ros.core.common import invert_transform, make_transform, transform_points
from tlessbot_ros.core.pose.buckets import PointBuckets
from tlessbot_ros.core.pose.cloud import (
    CloudParams,
    estimate_normals,
    remove_statistical_outliers,
    to_o3d,
    voxel_downsample,
)
from tlessbot_ros.core.pose.grid_kernels import (
    gauss_newton,
    inlier_fraction,
    self_visible,
    truncated_cost,
)
from tlessbot_ros.core.pose.templates import (
    CONTINUOUS_YAW_PERIOD,
    ObjectTemplates,
    TemplateDatabase,
    compute_fpfh,
)

METHODS = ('table', 'ransac')
COVERAGE_WEIGHT = 0.3


@dataclass(frozen=True)
class PoseParams:
    """Pose-estimation parameters (voxel scales are multiples of the database voxel, which is a
    fraction of the object's diameter).

    Attributes:
        method: 'table' (fast path, RANSAC fallback) or 'ransac'.
        yaw_step_deg: yaw hypothesis spacing of the table path.
        max_stable_poses: stable poses searched (most probable first).
        min_stable_probability: less likely stable poses are skipped.
        table_voxel_scale: the table path voxelises the ROI this much coarser than the
            templates (fewer points; the CAD surface is matched, not FPFH features).
        score_points: scene points used to score hypotheses (random, seeded subset).
        top_k: hypotheses refined in (yaw, x, y).
        flip_hypotheses: the best this many also enter turned by 180° in yaw.
        flip_axes: also refine the best turned by 180° about each object axis (through the
            surface centroid) and keep whichever fits best.
        final_candidates: refined table candidates scored fully (fitness and coverage).
        planar_iterations: Gauss-Newton steps of that refinement.
        icp_iterations: final 6-DOF point-to-plane ICP iterations.
        icp_distance_voxels: ICP correspondence distance (final iterations; the first ones
            start at twice this).
        icp_points: ICP uses at most this many scene points (evenly strided).
        inlier_voxels: distance of a scene point to the model surface counted as an inlier.
        inlier_plane_m: an inlier must also lie this close to the tangent plane of its nearest
            model sample (0: off); used for the final ranking.
        fallback_fitness: the table path falls back to RANSAC below this fitness.
        fallback: run that fallback at all (off: the table path's best is returned).
        fallback_templates: the fallback registers only the templates whose view is closest
            in rotation to the table path's best hypotheses, at most this many.
        fallback_max_iteration: RANSAC iterations per template in the fallback.
        fallback_budget_ms: the fallback starts no further template once this much time has
            passed since :meth:`PoseEstimator.estimate` began (bounds the worst case).
        ransac_distance_voxels, ransac_edge_length, ransac_mutual_filter,
        ransac_max_iteration, ransac_confidence: the SAC-IA settings (algo-notes §C.4).
        fpfh_radius_voxels, fpfh_max_nn: scene FPFH support (as in the templates).
        refine: refine RANSAC candidates with ICP (off = the paper's plain pipeline).
        ransac_candidates: RANSAC candidates (best by raw fitness) that get refined.
        seed: seeds the hypothesis subset and Open3D's RANSAC.
    """

    method: str = 'table'
    yaw_step_deg: float = 15.0
    max_stable_poses: int = 8
    min_stable_probability: float = 0.02
    table_voxel_scale: float = 1.5
    score_points: int = 200
    top_k: int = 6
    flip_hypotheses: int = 2
    flip_axes: bool = True
    final_candidates: int = 3
    planar_iterations: int = 6
    icp_iterations: int = 8
    icp_distance_voxels: float = 1.5
    icp_points: int = 250
    inlier_voxels: float = 1.0
    inlier_plane_m: float = 0.0025
    fallback_fitness: float = 0.7
    fallback: bool = True
    fallback_templates: int = 3
    fallback_max_iteration: int = 5000
    fallback_budget_ms: float = 60.0
    ransac_distance_voxels: float = 1.5
    ransac_edge_length: float = 0.9
    ransac_mutual_filter: bool = True
    ransac_max_iteration: int = 100000
    ransac_confidence: float = 0.999
    fpfh_radius_voxels: float = 5.0
    fpfh_max_nn: int = 100
    refine: bool = True
    ransac_candidates: int = 3
    seed: int = 0
    cloud: CloudParams = field(default_factory=CloudParams)

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f'method must be one of {METHODS}, got {self.method!r}')
        if not 0.0 < self.yaw_step_deg <= 180.0:
            raise ValueError(f'yaw_step_deg must be in (0, 180], got {self.yaw_step_deg}')
        if self.top_k < 1 or self.score_points < 10 or self.max_stable_poses < 1:
            raise ValueError('top_k and max_stable_poses must be >= 1, score_points >= 10')


@dataclass
class PoseCandidate:
    """One pose hypothesis after refinement.

    Attributes:
        T_camera_object: (4, 4) float64 pose in the ROI cloud's camera frame.
        fitness: fraction of scene points within ``inlier_voxels`` of the model surface.
        inlier_rmse_m: RMS point-to-model distance of those inliers, metres.
        coverage: fraction of the model surface facing the camera that has a scene point
            nearby (1 when unknown).
        method: 'table' or 'ransac'.
        template_index: the template a RANSAC candidate came from (-1 for the table path).
        stable_index: the stable pose of a table candidate (-1 otherwise).
    """

    T_camera_object: np.ndarray
    fitness: float
    inlier_rmse_m: float
    coverage: float = 1.0
    method: str = 'table'
    template_index: int = -1
    stable_index: int = -1

    @property
    def score(self) -> float:
        """Ranking score: fitness, plus a weaker coverage term (the back-face visibility test
        behind coverage ignores self-occlusion, so it only breaks near-ties)."""
        return self.fitness + COVERAGE_WEIGHT * self.coverage


@dataclass
class PoseResult:
    """Best and second-best candidates (paper: two templates) and per-stage times in ms."""

    obj_id: int
    best: PoseCandidate | None
    second: PoseCandidate | None
    n_points: int
    timings_ms: dict[str, float] = field(default_factory=dict)


def table_frame_from_plane(plane: np.ndarray, *, points_above: np.ndarray | None = None
                           ) -> np.ndarray:
    """A ``T_world_camera`` whose world z = 0 is a fitted table plane (z up, towards the camera).

    Args:
        plane: (4,) a, b, c, d of the plane in the camera frame (e.g. ``cloud.fit_plane``).
        points_above: unused placeholder for a future orientation check; the normal is turned
            towards the camera, which always looks at the table from above.
    """
    n = np.asarray(plane[:3], np.float64)
    norm = np.linalg.norm(n)
    if norm < 1e-9:
        raise ValueError('plane normal is zero')
    n, d = n / norm, float(plane[3]) / norm
    if d < 0:  # make the camera origin lie on the positive side: n . 0 + d > 0
        n, d = -n, -d
    origin = -d * n  # the foot of the camera centre on the plane
    x = np.cross([0.0, 1.0, 0.0], n)
    if np.linalg.norm(x) < 1e-6:
        x = np.cross([1.0, 0.0, 0.0], n)
    x /= np.linalg.norm(x)
    y = np.cross(n, x)
    T_camera_world = make_transform(np.stack([x, y, n], axis=1), origin)
    return invert_transform(T_camera_world)


def _rodrigues(omega: np.ndarray) -> np.ndarray:
    """Batched (K, 3) rotation vectors -> (K, 3, 3) matrices."""
    theta = np.linalg.norm(omega, axis=-1)[..., None, None]
    safe = np.where(theta > 1e-12, theta, 1.0)
    k = omega / safe[..., 0]
    K = np.zeros(omega.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2] = -k[..., 2], k[..., 1]
    K[..., 1, 0], K[..., 1, 2] = k[..., 2], -k[..., 0]
    K[..., 2, 0], K[..., 2, 1] = -k[..., 1], k[..., 0]
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + np.sin(theta) * K + (1 - np.cos(theta)) * (K @ K)


def _rotation_translation(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, 4, 4) poses -> contiguous float64 (K, 3, 3) rotations and (K, 3) translations."""
    T = np.asarray(T, np.float64).reshape(-1, 4, 4)
    return np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3])


def _rz(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros(np.shape(yaw) + (3, 3))
    R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
    return R


class PoseEstimator:
    """Pose of recognised objects against a :class:`TemplateDatabase`.

    Example:
        >>> estimator = PoseEstimator(TemplateDatabase.load('templates.npz'))
        >>> result = estimator.estimate(roi_points_c, 5, T_world_camera=side.T_world_camera)
        >>> result.best.T_camera_object
    """

    def __init__(self, database: TemplateDatabase, *, params: PoseParams = PoseParams()):
        self.database = database
        self.params = params

    # ----------------------------------------------------------------------------------- API
    def warm_up(self, obj_ids: Iterable[int] | None = None, *, features: bool = True) -> None:
        """Build every per-object cache now (nearest-point grids, KD-trees, scoring subsets,
        and with ``features`` the templates' FPFH), so the first frame that shows an object is
        not slower than the next: about 0.5 s per object, once. Each object's first template
        cloud is run through :meth:`estimate` with the template camera's pose."""
        ids = sorted(self.database.objects) if obj_ids is None else list(obj_ids)
        T_world_camera = self.database.params.get('T_world_camera')
        for obj_id in ids:
            obj = self.database[obj_id]
            obj.nearest_grid()
            obj.model_tree()
            if obj.templates:
                self.estimate(obj.templates[0].points.astype(np.float64), obj_id,
                              T_world_camera=None if T_world_camera is None
                              else np.asarray(T_world_camera, np.float64))
        if features:
            self.database.precompute_features(ids)

    def estimate(self, points_c: np.ndarray, obj_id: int, *,
                 T_world_camera: np.ndarray | None = None,
                 method: str | None = None, fallback: bool | None = None) -> PoseResult:
        """Pose of object ``obj_id`` from its ROI cloud.

        Args:
            points_c: (N, 3) ROI points in the camera optical frame, metres (from
                :func:`tlessbot_ros.core.pose.roi_cloud`).
            obj_id: the recognised T-LESS class.
            T_world_camera: (4, 4) camera pose in a world frame whose z = 0 plane is the table
                (needed by the table path; without it RANSAC is used).
            method: overrides ``params.method``.
            fallback: overrides ``params.fallback`` (False: the table path's answer however
                poor, e.g. to compare candidate classes quickly).

        Returns:
            a :class:`PoseResult`; ``best`` is None when the ROI has too few points.
        """
        start = time.perf_counter()
        points_c = np.asarray(points_c, np.float64)
        if points_c.ndim != 2 or points_c.shape[1] != 3:
            raise ValueError(f'points_c must be (N, 3), got shape {points_c.shape}')
        method = method or self.params.method
        if method not in METHODS:
            raise ValueError(f'method must be one of {METHODS}, got {method!r}')
        obj = self.database[obj_id]
        p = self.params
        timings: dict[str, float] = {}
        use_table = method == 'table' and T_world_camera is not None
        scene = self._prepare(points_c, obj, p.table_voxel_scale if use_table else 1.0, timings)
        result = PoseResult(int(obj_id), None, None, len(scene), timings)
        if len(scene) < 10:
            return result
        candidates: list[PoseCandidate] = []
        indices, max_iteration, deadline = None, p.ransac_max_iteration, None
        if use_table:
            t0 = time.perf_counter()
            candidates = self._table_path(scene, obj, np.asarray(T_world_camera, np.float64))
            timings['table'] = 1e3 * (time.perf_counter() - t0)
            fallback = p.fallback if fallback is None else fallback
            if not fallback or (candidates and candidates[0].fitness >= p.fallback_fitness):
                timings['total'] = timings['prep'] + timings['table']
                result.best, result.second = self._best_two(candidates)
                return result
            # Bounded fallback: a few templates near the table path's best views, fewer
            # iterations, and no new template once the budget is spent.
            indices = self._fallback_templates(obj, candidates)
            max_iteration = p.fallback_max_iteration
            deadline = start + 1e-3 * p.fallback_budget_ms
            scene = self._prepare(points_c, obj, 1.0, timings)
        t0 = time.perf_counter()
        candidates = self._rank(candidates + self._ransac_path(
            scene, obj, timings, indices=indices, max_iteration=max_iteration,
            deadline=deadline))
        timings['ransac'] = 1e3 * (time.perf_counter() - t0)
        timings['total'] = sum(v for k, v in timings.items() if k in ('prep', 'table', 'ransac'))
        result.best, result.second = self._best_two(candidates)
        return result

    def _fallback_templates(self, obj: ObjectTemplates,
                            candidates: list[PoseCandidate]) -> list[int]:
        """Templates whose object rotation in the (side) camera is nearest to the candidates'."""
        if not obj.templates:
            return []
        R_t = np.array([t.T_camera_object[:3, :3] for t in obj.templates])   # (T, 3, 3)
        angle = np.full(len(R_t), np.inf)
        for c in candidates[:2] or []:
            cos = (np.einsum('tij,ij->t', R_t, c.T_camera_object[:3, :3]) - 1.0) / 2.0
            angle = np.minimum(angle, np.arccos(np.clip(cos, -1.0, 1.0)))
        return [int(i) for i in np.argsort(angle, kind='stable')[:self.params.fallback_templates]]

    def _prepare(self, points_c: np.ndarray, obj: ObjectTemplates, scale: float,
                 timings: dict[str, float]) -> np.ndarray:
        """Voxel grid, then statistical outlier removal (cheaper after the grid)."""
        t0 = time.perf_counter()
        cloud = self.params.cloud
        scene, _ = voxel_downsample(points_c, obj.voxel_size_m * scale)
        scene = scene[remove_statistical_outliers(scene, neighbors=cloud.sor_neighbors,
                                                  std_ratio=cloud.sor_std_ratio)]
        timings['prep'] = timings.get('prep', 0.0) + 1e3 * (time.perf_counter() - t0)
        return scene

    # --------------------------------------------------------------------------- table path
    def _table_path(self, scene_c: np.ndarray, obj: ObjectTemplates,
                    T_world_camera: np.ndarray) -> list[PoseCandidate]:
        p = self.params
        voxel = obj.voxel_size_m
        grid = obj.nearest_grid()
        scene_w = transform_points(T_world_camera, scene_c)
        camera_w = T_world_camera[:3, 3]
        rng = np.random.default_rng(p.seed)
        sub = scene_w if len(scene_w) <= p.score_points else \
            scene_w[rng.choice(len(scene_w), p.score_points, replace=False)]
        centroid = scene_w.mean(axis=0)

        # Hypotheses: (stable pose, yaw) -> T_world_object, the position on the table set by
        # matching the centroid of the model surface facing the camera (back-face test) to the
        # ROI centroid.
        order = np.argsort(-obj.stable_probabilities)
        model, normals = self._model_subset(obj)
        view = camera_w - np.array([centroid[0], centroid[1], 0.0])
        poses, stable_ids = [], []
        for s in order[:p.max_stable_poses]:
            if obj.stable_probabilities[s] < p.min_stable_probability and poses:
                continue
            period = obj.yaw_periods[s]
            if period == CONTINUOUS_YAW_PERIOD:
                yaws = np.zeros(1)
            else:
                yaws = np.arange(0.0, period - 1e-9, np.radians(p.yaw_step_deg))
            Rz = _rz(yaws)                                          # (Y, 3, 3)
            T_s = obj.stable_poses[s]
            m_s = model @ T_s[:3, :3].T + T_s[:3, 3]                # resting, yaw 0
            n_s = normals @ T_s[:3, :3].T
            # (Rz n) . (view - Rz m) > 0  <=>  n . (Rz^T view) - n . m > 0
            visible = (n_s @ (view @ Rz).T - np.sum(n_s * m_s, axis=1)[:, None] > 0
                       ).astype(np.float64)                          # (M, Y)
            count = np.maximum(visible.sum(axis=0), 1.0)
            m_vis = (visible.T @ m_s) / count[:, None]               # (Y, 3), before the yaw
            m_vis = np.einsum('yij,yj->yi', Rz, m_vis)
            T = np.tile(np.eye(4), (len(yaws), 1, 1))
            T[:, :3, :3] = Rz @ T_s[:3, :3]
            T[:, :3, 3] = Rz @ T_s[:3, 3]
            T[:, :2, 3] += centroid[:2] - m_vis[:, :2]
            poses.append(T)
            stable_ids += [int(s)] * len(yaws)
        T_all = np.concatenate(poses)
        stable_ids_arr = np.array(stable_ids)

        # Score every hypothesis at once on the grid (truncated mean distance).
        tau = 2.0 * voxel
        cost = truncated_cost(*_rotation_translation(T_all), sub, grid.origin, grid.spacing,
                              grid.distance, tau)
        order_all = np.argsort(cost)
        keep = order_all[:p.top_k]
        # ... plus the best of every stable pose not yet represented (a part upside down can
        # lose on the coarse grid and win after refinement).
        extra = [order_all[stable_ids_arr[order_all] == s][0]
                 for s in np.unique(stable_ids_arr) if s not in stable_ids_arr[keep]]
        keep = np.concatenate([keep, np.array(extra, dtype=keep.dtype)])
        # Add the 180° yaw turn (about the vertical through the ROI centroid) of the best
        # hypotheses: near-symmetric parts fit both ways on the coarse grid.
        flip = make_transform(_rz(np.array(np.pi)), np.zeros(3))
        flip[:2, 3] = 2.0 * centroid[:2]
        keep = np.concatenate([keep, keep[:p.flip_hypotheses]])
        T_start = T_all[keep].copy()
        T_start[len(keep) - min(p.flip_hypotheses, len(keep) // 2):] = \
            flip @ T_start[len(keep) - min(p.flip_hypotheses, len(keep) // 2):]
        T_top, _ = self._planar_refine(T_start, sub, obj, grid, tau=voxel)
        # Rank the refined hypotheses by grid fitness (sharper than the truncated distance),
        # take the best and the best different one, add the half-turns of the best about the
        # object's axes (a part lying on one face or the opposite one fits the visible surface
        # almost equally), ICP them all, and score the few best fully (fitness + coverage).
        T_camera_world = invert_transform(T_world_camera)
        fit = self._grid_fitness(T_top, scene_w, obj)
        order = np.argsort(-fit, kind='stable')
        stable_top = stable_ids_arr[keep]
        starts = [(T_camera_world @ T_top[order[0]], int(stable_top[order[0]]))]
        for k in order[1:]:
            if _differs(T_top[k], T_top[order[0]]):
                starts.append((T_camera_world @ T_top[k], int(stable_top[k])))
                break
        if p.flip_axes:
            centre = obj.model_points.mean(axis=0).astype(np.float64)
            T_best = starts[0][0]
            for axis in np.eye(3):
                T = T_best.copy()
                T[:3, :3] = T_best[:3, :3] @ _rodrigues(np.pi * axis[None])[0]
                T[:3, 3] += T_best[:3, :3] @ centre - T[:3, :3] @ centre
                starts.append((T, -1))
        refined = self._icp_batch(scene_c, obj, np.array([T for T, _ in starts]))
        fit = self._grid_fitness(refined, scene_c, obj)
        scene_buckets = PointBuckets.build(scene_c, self._coverage_radius(obj))
        chosen: list[int] = []
        for k in np.argsort(-fit, kind='stable'):
            if len(chosen) == p.final_candidates:
                break
            if all(_differs(refined[k], refined[c]) for c in chosen):
                chosen.append(int(k))
        return self._rank([self._evaluate(scene_c, obj, refined[k], method='table',
                                          stable=starts[k][1], scene_buckets=scene_buckets)
                           for k in chosen])

    def _grid_fitness(self, T: np.ndarray, points: np.ndarray, obj: ObjectTemplates
                      ) -> np.ndarray:
        """(K,) fraction of ``points`` within ``inlier_voxels`` of the model for K poses of the
        object in the points' frame, via the nearest-sample grid."""
        grid = obj.nearest_grid()
        _, model = self._model_arrays(obj)
        return inlier_fraction(*_rotation_translation(T), np.ascontiguousarray(points),
                               grid.origin, grid.spacing, grid.index, model,
                               self.params.inlier_voxels * obj.voxel_size_m)

    @staticmethod
    def _model_subset(obj: ObjectTemplates, count: int = 800) -> tuple[np.ndarray, np.ndarray]:
        """The first ``count`` surface samples (they are in random order) for cheap scoring."""
        key = ('subset', count)
        if key not in obj._cache:
            obj._cache[key] = (obj.model_points[:count].astype(np.float64),
                               obj.model_normals[:count].astype(np.float64))
        return obj._cache[key]

    @staticmethod
    def _model_arrays(obj: ObjectTemplates) -> tuple[np.ndarray, np.ndarray]:
        """float64 model normals and points (converted once)."""
        if 'float64' not in obj._cache:
            obj._cache['float64'] = (obj.model_normals.astype(np.float64),
                                     obj.model_points.astype(np.float64))
        return obj._cache['float64']

    def _planar_refine(self, T: np.ndarray, points_w: np.ndarray, obj: ObjectTemplates,
                       grid, *, tau: float) -> tuple[np.ndarray, np.ndarray]:
        """(yaw, x, y) point-to-plane Gauss-Newton of K poses at once on the nearest grid;
        returns the poses and their final truncated mean distance (tau)."""
        p = self.params
        normals, model = self._model_arrays(obj)
        points_w = np.ascontiguousarray(points_w, np.float64)
        half = p.planar_iterations // 2
        max_d = obj.voxel_size_m * np.where(np.arange(p.planar_iterations) < half, 4.0, 2.0)
        R, t = gauss_newton(*_rotation_translation(T), points_w, grid.origin, grid.spacing,
                            grid.index, model, normals, max_d, True, 0.0)
        T = np.array(T, np.float64).reshape(-1, 4, 4)
        T[:, :3, :3], T[:, :3, 3] = R, t
        return T, truncated_cost(*_rotation_translation(T), points_w, grid.origin,
                                 grid.spacing, grid.distance, tau)

    # ------------------------------------------------------------------------- ransac path
    def _scene_features(self, scene_c: np.ndarray, obj: ObjectTemplates):
        p = self.params
        voxel = obj.voxel_size_m
        normals = estimate_normals(scene_c, radius_m=p.cloud.normal_radius_voxels * voxel,
                                   max_nn=p.cloud.normal_max_nn)
        fpfh = compute_fpfh(scene_c, normals, radius_m=p.fpfh_radius_voxels * voxel,
                            max_nn=p.fpfh_max_nn)
        return normals, fpfh

    def _ransac_path(self, scene_c: np.ndarray, obj: ObjectTemplates,
                     timings: dict[str, float], *, indices: list[int] | None = None,
                     max_iteration: int | None = None,
                     deadline: float | None = None) -> list[PoseCandidate]:
        p = self.params
        t0 = time.perf_counter()
        normals, fpfh = self._scene_features(scene_c, obj)
        timings['features'] = 1e3 * (time.perf_counter() - t0)
        raw = register_templates(scene_c, normals, fpfh, obj, params=p, template_indices=indices,
                                 max_iteration=max_iteration, deadline=deadline)
        if not p.refine:  # the paper: templates ranked by RANSAC fitness alone
            for c in raw:
                c.coverage = 0.0
            return raw
        raw.sort(key=lambda c: -c.fitness)
        out = []
        for c in raw[:p.ransac_candidates]:
            T = self._icp(scene_c, obj, c.T_camera_object)
            out.append(self._evaluate(scene_c, obj, T, method='ransac',
                                      template=c.template_index))
        return out

    # --------------------------------------------------------------- refinement and scoring
    def _icp(self, scene_c: np.ndarray, obj: ObjectTemplates, T_camera_object: np.ndarray,
             *, iterations: int | None = None) -> np.ndarray:
        """6-DOF point-to-plane ICP of the scene onto the model surface samples."""
        return self._icp_batch(scene_c, obj, np.asarray(T_camera_object)[None],
                               iterations=iterations)[0]

    def _icp_batch(self, scene_c: np.ndarray, obj: ObjectTemplates, T_camera_object: np.ndarray,
                   *, iterations: int | None = None) -> np.ndarray:
        """Point-to-plane ICP (Chen & Medioni 1992) of K (K, 4, 4) starting poses at once; the
        model's nearest sample comes from the nearest-sample grid (O(1) per point)."""
        p = self.params
        grid = obj.nearest_grid()
        normals, model = self._model_arrays(obj)
        T = np.array(T_camera_object, np.float64).reshape(-1, 4, 4)
        if len(scene_c) > p.icp_points:
            scene_c = scene_c[::int(np.ceil(len(scene_c) / p.icp_points))]
        iterations = p.icp_iterations if iterations is None else iterations
        scene_c = np.ascontiguousarray(scene_c, np.float64)
        max_d = p.icp_distance_voxels * obj.voxel_size_m * np.where(
            np.arange(iterations) < iterations // 2, 2.0, 1.0)
        R, t = gauss_newton(*_rotation_translation(T), scene_c, grid.origin, grid.spacing,
                            grid.index, model, normals, max_d, False, 1e-6)
        T[:, :3, :3], T[:, :3, 3] = R, t
        return T

    def _evaluate(self, scene_c: np.ndarray, obj: ObjectTemplates, T_camera_object: np.ndarray,
                  *, method: str, stable: int = -1, template: int = -1,
                  scene_buckets: PointBuckets | None = None) -> PoseCandidate:
        """Fitness / RMSE (scene -> model) and coverage (visible model -> scene).

        ``scene_buckets``: :class:`PointBuckets` of ``scene_c`` with an edge of at least
        :meth:`_coverage_radius` (built here when not given).
        """
        inlier = self.params.inlier_voxels * obj.voxel_size_m
        q = transform_points(invert_transform(T_camera_object), scene_c)
        dist, index = obj.model_buckets(inlier).nearest(q, inlier)
        ok = np.isfinite(dist)
        if self.params.inlier_plane_m > 0 and ok.any():
            # ... and within inlier_plane_m of the tangent plane there: small features (a few
            # mm) decide between near-symmetric poses that a voxel-wide radius cannot tell apart
            normals_all, model_all = self._model_arrays(obj)
            i = index[ok]
            plane = np.abs(np.sum(normals_all[i] * (q[ok] - model_all[i]), axis=1))
            ok[np.flatnonzero(ok)[plane >= self.params.inlier_plane_m]] = False
        fitness = float(ok.mean()) if len(ok) else 0.0
        rmse = float(np.sqrt(np.mean(dist[ok] ** 2))) if ok.any() else np.inf
        model, normals = self._model_subset(obj)
        model_c = model @ T_camera_object[:3, :3].T + T_camera_object[:3, 3]
        normals_c = normals @ T_camera_object[:3, :3].T
        visible = self_visible(model_c, normals_c, 0.5 * obj.voxel_size_m
                               / max(float(np.median(scene_c[:, 2])), 1e-3), obj.voxel_size_m)
        coverage = 1.0
        if visible.any():
            radius = self._coverage_radius(obj)
            scene_buckets = scene_buckets or PointBuckets.build(scene_c, radius)
            coverage = float(scene_buckets.any_within(model_c[visible], radius).mean())
        return PoseCandidate(np.asarray(T_camera_object, np.float64), fitness, rmse, coverage,
                             method, template, stable)

    @staticmethod
    def _coverage_radius(obj: ObjectTemplates) -> float:
        """A visible model sample is covered by a scene point within this distance (m)."""
        return 2.0 * obj.voxel_size_m

    @staticmethod
    def _rank(candidates: list[PoseCandidate]) -> list[PoseCandidate]:
        return sorted(candidates, key=lambda c: (-c.score, c.inlier_rmse_m))

    @staticmethod
    def _best_two(candidates: list[PoseCandidate]) -> tuple[PoseCandidate | None,
                                                             PoseCandidate | None]:
        """Best, and the best one that differs from it by > 1 cm or > 5° (else None)."""
        if not candidates:
            return None, None
        ranked = PoseEstimator._rank(candidates)
        best = ranked[0]
        for c in ranked[1:]:
            if _differs(c.T_camera_object, best.T_camera_object):
                return best, c
        return best, None


def _differs(T_a: np.ndarray, T_b: np.ndarray, *, t_m: float = 0.01, r_deg: float = 5.0) -> bool:
    """True when two poses differ by more than ``t_m`` or ``r_deg``."""
    cos = (np.trace(T_a[:3, :3].T @ T_b[:3, :3]) - 1.0) / 2.0
    return bool(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]) > t_m or
                np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))) > r_deg)


def register_templates(scene_c: np.ndarray, scene_normals: np.ndarray, scene_fpfh: np.ndarray,
                       obj: ObjectTemplates, *, params: PoseParams = PoseParams(),
                       template_indices: list[int] | None = None,
                       max_iteration: int | None = None,
                       deadline: float | None = None) -> list[PoseCandidate]:
    """FPFH + RANSAC (SAC-IA) of each template against a scene cloud, no refinement.

    Args:
        scene_c: (N, 3) voxelised scene points (camera frame); scene_normals (N, 3);
            scene_fpfh (N, 33) float32 from :func:`~tlessbot_ros.core.pose.compute_fpfh`.
        obj: the object's templates.
        template_indices: templates to try (default all).
        max_iteration: RANSAC iterations per template (default ``params.ransac_max_iteration``).
        deadline: a ``time.perf_counter()`` value after which no further template is started
            (at least one always is).

    Returns:
        one candidate per template with Open3D's fitness / inlier RMSE (coverage 1).
    """
    reg = o3d.pipelines.registration
    voxel = obj.voxel_size_m
    distance = params.ransac_distance_voxels * voxel
    target = to_o3d(scene_c, scene_normals)
    target_feature = reg.Feature()
    target_feature.data = np.asarray(scene_fpfh, np.float64).T
    checkers = [reg.CorrespondenceCheckerBasedOnEdgeLength(params.ransac_edge_length),
                reg.CorrespondenceCheckerBasedOnDistance(distance)]
    out = []
    indices = range(len(obj.templates)) if template_indices is None else template_indices
    iterations = int(max_iteration or params.ransac_max_iteration)
    for i in indices:
        if deadline is not None and out and time.perf_counter() > deadline:
            break
        template = obj.templates[i]
        template_normals, template_fpfh = obj.features(i)
        source = to_o3d(template.points, template_normals)
        source_feature = reg.Feature()
        source_feature.data = np.asarray(template_fpfh, np.float64).T
        o3d.utility.random.seed(int(params.seed))
        # Errors only: the mutual filter's "too few correspondences, fall back" warning is
        # expected on small ROI clouds and would flood a node's log every frame.
        with o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error):
            result = reg.registration_ransac_based_on_feature_matching(
                source=source, target=target, source_feature=source_feature,
                target_feature=target_feature, mutual_filter=params.ransac_mutual_filter,
                max_correspondence_distance=distance,
                estimation_method=reg.TransformationEstimationPointToPoint(with_scaling=False),
                ransac_n=3, checkers=checkers,
                criteria=reg.RANSACConvergenceCriteria(max_iteration=iterations,
                                                       confidence=params.ransac_confidence))
        T_scene_template = np.asarray(result.transformation)
        out.append(PoseCandidate(T_scene_template @ template.T_camera_object,
                                 float(result.fitness), float(result.inlier_rmse),
                                 method='ransac', template_index=int(i)))
    return out

