"""6D pose of a recognised object from its ROI cloud (paper §3.3, §6.2, and a faster path).

Two estimators share one refinement and one scoring (:class:`~tlessbot_ros.core.pose.Refiner`,
:mod:`tlessbot_ros.core.pose.refinement`; pass another as ``PoseEstimator(refiner=...)``):

* ``'ransac'`` (:mod:`tlessbot_ros.core.pose.ransac`) – the paper's method, improved: FPFH +
  sample-consensus initial alignment (Open3D RANSAC on feature matches, mutual filter,
  edge-length and distance checkers) of each template of the recognised class against the ROI
  cloud, then point-to-plane ICP against the CAD surface; best and second-best candidates by
  score after refinement.
* ``'table'`` (default) – parts rest on the table, so the pose is one of the part's stable
  poses turned by a yaw and shifted on the plane.
  For every stable pose and yaw hypothesis (yaw steps pruned by the pose's rotational symmetry)
  the position on the plane is set by matching the centroid of the model surface facing the
  camera to the ROI centroid, every hypothesis is scored at once through a precomputed
  nearest-sample grid of the model, the best few are refined in (yaw, x, y) by point-to-plane
  Gauss-Newton steps on that grid, and the winner gets a full 6-DOF point-to-plane ICP.
  This needs the table frame: ``T_world_camera`` with the table at world z = 0 (the rig's
  extrinsics, or the plane seen in the depth: :mod:`tlessbot_ros.core.common.table_plane`).
  When its fit stays below ``fallback_fitness`` (a part leaning on another), or without a
  table frame, or always with ``force_fallback``, the part goes to the fallback:
  ``fallback_method='views'`` the bounded 6-DOF search of
  :mod:`tlessbot_ros.core.pose.fallback` (tens of ms), ``'templates'`` the former FPFH +
  RANSAC against the templates.

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
from functools import partial

import numpy as np

from tlessbot_ros.core.common import invert_transform, make_transform, transform_points
from tlessbot_ros.core.common.table_plane import table_frame_from_plane  # noqa: F401 (API)
from tlessbot_ros.core.pose.buckets import PointBuckets
from tlessbot_ros.core.pose.candidates import PoseCandidate, PoseResult, poses_differ
from tlessbot_ros.core.pose.cloud import remove_statistical_outliers, voxel_downsample
from tlessbot_ros.core.pose.database import (
    ObjectTemplates,
    TemplateDatabase,
)
from tlessbot_ros.core.pose.fallback import fallback_candidates, view_grid
from tlessbot_ros.core.pose.hypotheses import (
    HALF_TURNS,
    resting_hypotheses,
    rotations_about_z,
)
from tlessbot_ros.core.pose.image_box import ImageBox, box_cover, centred_on_box
from tlessbot_ros.core.pose.params import METHODS, PoseParams
from tlessbot_ros.core.pose.ransac import ransac_candidates
from tlessbot_ros.core.pose.refinement import Refiner
from tlessbot_ros.core.pose.resting import stable_directions


def after_polish(polished: list[PoseCandidate], margin: float) -> list[PoseCandidate]:
    """The table path's finalists after the polish, given in their rank order before it
    (``polished[0]`` was the winner), ranked: the former winner stays first unless another
    finalist's fitness is higher by more than ``margin`` (then the fittest of those comes
    first); the others follow by score (:meth:`PoseEstimator._rank`). ``margin`` >= 1: by score
    alone.

    The polish lets every finalist converge, a wrong one too, so it only overturns the choice
    on clear evidence: more ROI points explained. The score's coverage term cannot be that
    evidence: it comes from a back-face test that ignores self-occlusion, so a pose turned by
    ~180° (90° for a part with a 180° symmetry) can cover more than the right pose while it
    explains fewer points; and between two converged near-equal fits neither term tells them
    apart (examples: docs/bench/code-figures.md). In box mode the fitness is weighed by the
    box's cover (:attr:`PoseCandidate.box_fitness`).
    """
    ranked = PoseEstimator._rank(polished)
    if margin >= 1.0 or len(polished) < 2:
        return ranked
    first = polished[0]
    fitter = [c for c in polished[1:] if c.box_fitness > first.box_fitness + margin]
    if fitter:
        first = max(fitter, key=lambda c: c.box_fitness)
    return [first] + [c for c in ranked if c is not first]


class PoseEstimator:
    """Pose of recognised objects against a :class:`TemplateDatabase`.

    Args:
        database: the templates.
        params: the pose settings.
        refiner: refinement and scoring of the hypotheses (default ``Refiner(params)``); any
            object with :class:`~tlessbot_ros.core.pose.Refiner`'s methods will do.

    Example:
        >>> estimator = PoseEstimator(TemplateDatabase.load('templates.npz'))
        >>> result = estimator.estimate(roi_points_c, 5, T_world_camera=side.T_world_camera)
        >>> result.best.T_camera_object
    """

    def __init__(self, database: TemplateDatabase, *, params: PoseParams = PoseParams(),
                 refiner: Refiner | None = None):
        self.database = database
        self.params = params
        self.refiner = Refiner(params) if refiner is None else refiner


    # ----------------------------------------------------------------------------------- API
    def warm_up(self, obj_ids: Iterable[int] | None = None, *, features: bool = True) -> None:
        """Build every per-object cache now (nearest-point grids, KD-trees, scoring subsets, the
        fallback's view grid, every meshed part's stable poses, and with ``features`` the
        templates' FPFH), so the first frame
        that shows an object is not slower than the next (a cost paid once per object). Each
        object's first template cloud is run through :meth:`estimate` with the template
        camera's pose."""
        ids = sorted(self.database.objects) if obj_ids is None else list(obj_ids)
        T_world_camera = self.database.params.get('T_world_camera')
        p = self.params
        for obj_id in ids:
            obj = self.database[obj_id]
            obj.nearest_grid()
            obj.model_tree()
            stable_directions(obj)   # the resting-pose prior's stable poses (mesh: once)
            if p.fallback_method == 'views':
                view_grid(obj, directions=p.fallback_directions,
                          in_plane_steps=p.fallback_in_plane_steps)
            if obj.templates:
                self.estimate(obj.templates[0].points.astype(np.float64), obj_id,
                              T_world_camera=None if T_world_camera is None
                              else np.asarray(T_world_camera, np.float64))
        if features:
            self.database.precompute_features(ids)

    def estimate(self, points_c: np.ndarray, obj_id: int, *,
                 T_world_camera: np.ndarray | None = None,
                 method: str | None = None, fallback: bool | None = None,
                 polish: bool | None = None,
                 scenes: dict[float, np.ndarray] | None = None,
                 box: ImageBox | None = None) -> PoseResult:
        """Pose of object ``obj_id`` from its ROI cloud.

        Args:
            points_c: (N, 3) ROI points in the camera optical frame, metres (from
                :func:`tlessbot_ros.core.pose.roi_cloud`).
            obj_id: the recognised T-LESS class.
            T_world_camera: (4, 4) camera pose in a world frame whose z = 0 plane is the table
                (needed by the table path; without it the fallback is used).
            method: overrides ``params.method``.
            fallback: overrides ``params.fallback`` (False: the table path's answer however
                poor, e.g. to compare candidate classes quickly).
            polish: whether the table path's finalists get ``polish_iterations`` more ICP
                steps before they are ranked (default: when that is > 0). False leaves them
                at the short ICP of every start, so that candidate classes are compared on
                equal terms (a wrong class gains from the polish too); :meth:`polish` then
                polishes the chosen class's finalists.
            scenes: the ROI cloud voxelised and cleaned of outliers, by voxel edge (m): a
                caller that fits several classes to the same ``points_c`` passes the same
                dict to each call, and a class whose voxel edge was seen already reuses that
                cloud (it is the same cloud; it is filled here and must not be modified).
            box: the part's given 2D box (box mode): every pose is weighed by the share of
                the box it covers (:mod:`~tlessbot_ros.core.pose.image_box`); None: not.

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
        use_table = method == 'table' and T_world_camera is not None and not p.force_fallback
        scene = self._prepare(points_c, obj, p.table_voxel_scale if use_table else 1.0, timings,
                              scenes)
        result = PoseResult(int(obj_id), None, None, len(scene), timings)
        if len(scene) < 10:
            return result
        candidates: list[PoseCandidate] = []
        if use_table:
            t0 = time.perf_counter()
            polish = p.polish_iterations > 0 and (polish is None or polish)
            candidates = self._table_path(scene, obj, np.asarray(T_world_camera, np.float64),
                                          polish=polish, box=box)
            timings['table'] = 1e3 * (time.perf_counter() - t0)
            fallback = p.fallback if fallback is None else fallback
            if not fallback or (candidates and candidates[0].fitness >= p.fallback_fitness):
                timings['total'] = timings['prep'] + timings['table']
                result.best, result.second = self._best_two(candidates)
                result.finalists, result.polished = candidates, polish
                return result
            scene = self._prepare(points_c, obj, 1.0, timings, scenes)
        candidates = self._fallback_path(scene, obj, candidates, timings, method=method,
                                         after_table=use_table, start=start,
                                         T_world_camera=T_world_camera)
        if box is not None:   # the fallback's candidates weighed as the table path's
            for candidate, cover in zip(candidates, box_cover(
                    np.array([c.T_camera_object for c in candidates]), obj, box)):
                candidate.box_cover = float(cover)
            candidates = self._rank(candidates)
        timings['total'] = sum(v for k, v in timings.items()
                               if k in ('prep', 'table', 'ransac', 'fallback'))
        result.best, result.second = self._best_two(candidates)
        return result

    def _fallback_path(self, scene: np.ndarray, obj: ObjectTemplates,
                       candidates: list[PoseCandidate], timings: dict[str, float], *,
                       method: str, after_table: bool, start: float,
                       T_world_camera: np.ndarray | None = None) -> list[PoseCandidate]:
        """The table path's ``candidates`` with the fallback's (view grid or RANSAC), ranked;
        ``after_table``: the table path ran first and its fit was poor (bounded fallback);
        ``T_world_camera``: the table frame, if known (the view grid drops the table by it)."""
        p = self.params
        t0 = time.perf_counter()
        if method == 'table' and p.fallback_method == 'views':
            candidates = self._rank(candidates + fallback_candidates(
                scene, obj, timings, params=p, refiner=self.refiner,
                starts=np.array([c.T_camera_object for c in candidates[:2]]).reshape(-1, 4, 4),
                deadline=self._deadline(start), T_world_camera=T_world_camera))
            timings['fallback'] = 1e3 * (time.perf_counter() - t0)
        else:
            indices, max_iteration, deadline = None, p.ransac_max_iteration, None
            if after_table:
                # Today's fallback: a few templates near the table path's best views, fewer
                # iterations, and no new template once the budget is spent.
                indices = self._fallback_templates(obj, candidates)
                max_iteration = p.fallback_max_iteration
                deadline = self._deadline(start)
            candidates = self._rank(candidates + ransac_candidates(
                scene, obj, timings, params=p, refiner=self.refiner, indices=indices,
                max_iteration=max_iteration, deadline=deadline))
            timings['ransac'] = 1e3 * (time.perf_counter() - t0)
        return candidates

    def _deadline(self, start: float) -> float | None:
        """The ``time.perf_counter()`` value at which the fallback stops early, or None when
        ``fallback_budget_ms`` is 0 (the default: the work is bounded by its counts alone)."""
        budget_ms = self.params.fallback_budget_ms
        return start + 1e-3 * budget_ms if budget_ms > 0 else None

    def polish(self, points_c: np.ndarray, result: PoseResult, *,
               scenes: dict[float, np.ndarray] | None = None,
               box: ImageBox | None = None) -> PoseResult:
        """``result``'s table-path finalists with ``polish_iterations`` more ICP steps on every
        ROI point, scored and ranked again: the second half of an :meth:`estimate` call made
        with ``polish=False`` (for the class that the unpolished fits chose).

        Args:
            points_c: (N, 3) the ROI points ``result`` was estimated from (camera optical
                frame, metres).
            result: that estimate.
            scenes: the prepared clouds, as in :meth:`estimate` (the table path's is reused).
            box: the part's given box, as in :meth:`estimate`.

        Returns:
            a new :class:`PoseResult` (``timings_ms['polish']`` added); ``result`` itself when
            there is nothing to polish (no table-path finalists, already polished, or
            ``polish_iterations`` 0).
        """
        p = self.params
        if result.polished or not result.finalists or p.polish_iterations == 0:
            return result
        t0 = time.perf_counter()
        obj = self.database[result.obj_id]
        timings = dict(result.timings_ms)
        scene = self._prepare(np.asarray(points_c, np.float64), obj, p.table_voxel_scale,
                              timings, scenes)
        finalists = self._polish_finalists(scene, obj, result.finalists, box=box)
        timings['polish'] = 1e3 * (time.perf_counter() - t0)
        timings['total'] = timings.get('total', 0.0) + timings['polish']
        best, second = self._best_two(finalists)
        return PoseResult(result.obj_id, best, second, result.n_points, timings, finalists,
                          True)

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
                 timings: dict[str, float], scenes: dict[float, np.ndarray] | None = None
                 ) -> np.ndarray:
        """Voxel grid, then statistical outlier removal (cheaper after the grid); taken from
        ``scenes`` when it holds this voxel edge's cloud (see :meth:`estimate`)."""
        t0 = time.perf_counter()
        voxel = obj.voxel_size_m * scale
        scene = None if scenes is None else scenes.get(voxel)
        if scene is None:
            cloud = self.params.cloud
            scene, _ = voxel_downsample(points_c, voxel)
            scene = scene[remove_statistical_outliers(scene, neighbors=cloud.sor_neighbors,
                                                      std_ratio=cloud.sor_std_ratio)]
            if scenes is not None:
                scenes[voxel] = scene
        timings['prep'] = timings.get('prep', 0.0) + 1e3 * (time.perf_counter() - t0)
        return scene

    # --------------------------------------------------------------------------- table path
    def _table_path(self, scene_c: np.ndarray, obj: ObjectTemplates,
                    T_world_camera: np.ndarray, *, polish: bool,
                    box: ImageBox | None = None) -> list[PoseCandidate]:
        p = self.params
        voxel = obj.voxel_size_m
        refiner = self.refiner
        scene_w = transform_points(T_world_camera, scene_c)
        rng = np.random.default_rng(p.seed)
        sub = scene_w if len(scene_w) <= p.score_points else \
            scene_w[rng.choice(len(scene_w), p.score_points, replace=False)]
        centroid = scene_w.mean(axis=0)
        T_all, stable_ids_arr = self._hypotheses(obj, centroid, T_world_camera[:3, 3])
        if box is not None:   # each hypothesis also placed where the box says
            T_all = np.concatenate([T_all, centred_on_box(T_all, obj, box, T_world_camera)])
            stable_ids_arr = np.concatenate([stable_ids_arr, stable_ids_arr])

        # Score every hypothesis at once on the grid (truncated mean distance).
        tau = 2.0 * voxel
        cost = refiner.truncated_cost(T_all, sub, obj, tau=tau)
        if box is not None:   # the share explained (1 - cost / tau) times the box's cover
            cost = tau - (tau - cost) * box_cover(invert_transform(T_world_camera) @ T_all,
                                                  obj, box)
        order_all = np.argsort(cost)
        keep = order_all[:p.top_k]
        # ... plus the best of every stable pose not yet represented (a part upside down can
        # lose on the coarse grid and win after refinement).
        extra = [order_all[stable_ids_arr[order_all] == s][0]
                 for s in np.unique(stable_ids_arr) if s not in stable_ids_arr[keep]]
        keep = np.concatenate([keep, np.array(extra, dtype=keep.dtype)])
        # Add the 180° yaw turn (about the vertical through the ROI centroid) of the best
        # hypotheses: near-symmetric parts fit both ways on the coarse grid.
        flip = make_transform(rotations_about_z(np.array(np.pi)), np.zeros(3))
        flip[:2, 3] = 2.0 * centroid[:2]
        keep = np.concatenate([keep, keep[:p.flip_hypotheses]])
        T_start = T_all[keep].copy()
        T_start[len(keep) - min(p.flip_hypotheses, len(keep) // 2):] = \
            flip @ T_start[len(keep) - min(p.flip_hypotheses, len(keep) // 2):]
        T_top, _ = refiner.planar(T_start, sub, obj, tau=voxel)
        starts = self._icp_starts(T_top, stable_ids_arr[keep], scene_w, obj, T_world_camera,
                                  box)
        refined = refiner.icp_batch(scene_c, obj, np.array([T for T, _ in starts]))
        fit = refiner.grid_fitness(refined, scene_c, obj)
        if box is not None:
            fit = fit * box_cover(refined, obj, box)
        chosen: list[int] = []
        for k in np.argsort(-fit, kind='stable'):
            if len(chosen) == p.final_candidates:
                break
            if all(poses_differ(refined[k], refined[c]) for c in chosen):
                chosen.append(int(k))
        # one scene lookup for both scorings (before and after the polish)
        lookup = self._scene_lookup(scene_c, obj)
        ranked = self._rank(self._score_finalists(scene_c, obj, refined[chosen],
                                                  [starts[k][1] for k in chosen], lookup, box))
        return self._polish_finalists(scene_c, obj, ranked, lookup, box) if polish else ranked

    def _scene_lookup(self, scene_c: np.ndarray, obj: ObjectTemplates
                      ) -> tuple[PointBuckets, float]:
        """What scoring poses of ``obj`` against ``scene_c`` needs of the scene alone: its
        :class:`PointBuckets` for the coverage and its median depth (m)."""
        return (PointBuckets.build(scene_c, self.refiner.coverage_radius(obj)),
                float(np.median(scene_c[:, 2])))

    def _score_finalists(self, scene_c: np.ndarray, obj: ObjectTemplates, T: np.ndarray,
                         stables: list[int],
                         lookup: tuple[PointBuckets, float] | None = None,
                         box: ImageBox | None = None) -> list[PoseCandidate]:
        """The (K, 4, 4) ``T_camera_object`` table-path finalists (their stable-pose indices
        ``stables``) scored fully (fitness, RMSE, coverage; the cover of ``box`` when given),
        in the order given; ``lookup``: :meth:`_scene_lookup` of this scene and object (built
        here when not given)."""
        refiner = self.refiner
        scene_buckets, scene_depth_m = lookup or self._scene_lookup(scene_c, obj)
        scored = [refiner.evaluate(scene_c, obj, T_k, method='table', stable=stable,
                                   scene_buckets=scene_buckets, scene_depth_m=scene_depth_m)
                  for T_k, stable in zip(T, stables)]
        if box is not None:
            for candidate, cover in zip(scored, box_cover(T, obj, box)):
                candidate.box_cover = float(cover)
        return scored

    def _polish_finalists(self, scene_c: np.ndarray, obj: ObjectTemplates,
                          ranked: list[PoseCandidate],
                          lookup: tuple[PointBuckets, float] | None = None,
                          box: ImageBox | None = None) -> list[PoseCandidate]:
        """The ranked finalists after ``polish_iterations`` more ICP steps on every ROI point,
        scored again and ranked by :func:`after_polish`; those more than
        ``polish_margin_fitness`` behind the former winner's fitness are not polished and keep
        their fit. ``lookup`` and ``box``: as in :meth:`_score_finalists`."""
        p = self.params
        # The short ICP of the many starts stops a few degrees short on parts with a
        # (near-)symmetry axis (measured: fitness 0.85 where the converged pose scores 0.99),
        # and then a turned pose ranks as high as the right one: the few finalists converge.
        # Each finalist polished costs an ICP and a scoring more, and one far behind the
        # winner in fitness does not become the winner (on 12 simulated scenes those that did
        # had been at most 0.13 behind, most within 0.06; polish_margin_fitness 0.2): those
        # are left as they are.
        near = [k for k, c in enumerate(ranked)
                if k == 0 or c.box_fitness >= ranked[0].box_fitness - p.polish_margin_fitness]
        T = self.refiner.icp_batch(scene_c, obj,
                                   np.array([ranked[k].T_camera_object for k in near]),
                                   iterations=p.polish_iterations, points=len(scene_c),
                                   distance_m=p.polish_distance_voxels * obj.voxel_size_m)
        polished = list(ranked)
        for k, candidate in zip(near, self._score_finalists(
                scene_c, obj, T, [ranked[k].stable_index for k in near], lookup, box)):
            polished[k] = candidate
        return after_polish(polished, p.polish_overturn_fitness)

    def _hypotheses(self, obj: ObjectTemplates, centroid: np.ndarray, camera_w: np.ndarray
                    ) -> tuple[np.ndarray, np.ndarray]:
        """(H, 4, 4) ``T_world_object`` of every (stable pose, yaw) hypothesis and (H,) their
        stable-pose indices; the position on the table is set by matching the centroid of the
        model surface facing the camera (back-face test) to the ROI centroid (world frame)."""
        p = self.params
        order = np.argsort(-obj.stable_probabilities)
        view = camera_w - np.array([centroid[0], centroid[1], 0.0])
        poses: list[np.ndarray] = []
        stable_ids: list[int] = []
        for s in order[:p.max_stable_poses]:
            if obj.stable_probabilities[s] < p.min_stable_probability and poses:
                continue
            rest = obj.derived(('resting', int(s), p.yaw_step_deg),
                               partial(resting_hypotheses, obj, int(s), p.yaw_step_deg))
            # (Rz n) . (view - Rz m) > 0  <=>  n . (Rz^T view) - n . m > 0
            facing = rest.normals @ (view @ rest.Rz).T - rest.normal_dot_point[:, None] > 0
            visible = facing.astype(np.float64)                      # (M, Y)
            count = np.maximum(visible.sum(axis=0), 1.0)
            m_vis = (visible.T @ rest.points) / count[:, None]       # (Y, 3), before the yaw
            m_vis = np.einsum('yij,yj->yi', rest.Rz, m_vis)
            T = rest.T_world_object.copy()
            T[:, :2, 3] += centroid[:2] - m_vis[:, :2]
            poses.append(T)
            stable_ids += [int(s)] * len(T)
        return np.concatenate(poses), np.array(stable_ids)

    def _icp_starts(self, T_top: np.ndarray, stable_top: np.ndarray, scene_w: np.ndarray,
                    obj: ObjectTemplates, T_world_camera: np.ndarray,
                    box: ImageBox | None = None) -> list[tuple[np.ndarray, int]]:
        """``(T_camera_object, stable index)`` starts of the final ICP from the planar-refined
        ``T_top`` (world frame); with ``box``, ranked by fitness times the box's cover."""
        # Rank the refined hypotheses by grid fitness (sharper than the truncated distance),
        # take the best and the best different one, add the half-turns of the best about the
        # object's axes (a part lying on one face or the opposite one fits the visible surface
        # almost equally), ICP them all, and score the few best fully (fitness + coverage).
        T_camera_world = invert_transform(T_world_camera)
        fit = self.refiner.grid_fitness(T_top, scene_w, obj)
        if box is not None:
            fit = fit * box_cover(T_camera_world @ T_top, obj, box)
        order = np.argsort(-fit, kind='stable')
        starts = [(T_camera_world @ T_top[order[0]], int(stable_top[order[0]]))]
        for k in order[1:]:
            if poses_differ(T_top[k], T_top[order[0]]):
                starts.append((T_camera_world @ T_top[k], int(stable_top[k])))
                break
        if self.params.flip_axes:
            centre = obj.derived('surface_centre',
                                 lambda: obj.model_points.mean(axis=0).astype(np.float64))
            T_best = starts[0][0]
            for half_turn in HALF_TURNS:
                T = T_best.copy()
                T[:3, :3] = T_best[:3, :3] @ half_turn
                T[:3, 3] += T_best[:3, :3] @ centre - T[:3, :3] @ centre
                starts.append((T, -1))
        return starts

    @staticmethod
    def _rank(candidates: list[PoseCandidate]) -> list[PoseCandidate]:
        return sorted(candidates, key=lambda c: (-c.score, c.inlier_rmse_m))

    @staticmethod
    def _best_two(ranked: list[PoseCandidate]) -> tuple[PoseCandidate | None,
                                                         PoseCandidate | None]:
        """Of candidates ranked best first (each path ranks its own: :meth:`_rank`, and the
        table path's :func:`after_polish`), the best, and the best one that differs
        from it by > 1 cm or > 5° (else None)."""
        if not ranked:
            return None, None
        best = ranked[0]
        for c in ranked[1:]:
            if poses_differ(c.T_camera_object, best.T_camera_object):
                return best, c
        return best, None

