"""Refinement and scoring of pose hypotheses against an object's surface samples.

:class:`Refiner` holds everything the pose paths do to a hypothesis once it exists: the
(yaw, x, y) point-to-plane Gauss-Newton of the table path, the 6-DOF point-to-plane ICP
(Chen & Medioni 1992) of both paths, the grid scores used to rank hypotheses, and the full
evaluation (fitness, inlier RMSE, coverage) that makes a :class:`PoseCandidate`. All of them
look the model up through the object's nearest-sample grid
(:meth:`~tlessbot_ros.core.pose.ObjectTemplates.nearest_grid`), O(1) per point, with the fused
kernels of :mod:`tlessbot_ros.core.pose.grid_kernels`.

To try another refinement, subclass :class:`Refiner` (or write a class with the same methods)
and pass it as ``PoseEstimator(database, refiner=...)``; the estimator's hypothesis search and
ranking stay as they are.

Poses are (K, 4, 4) float64 ``T_frame_object``; points (N, 3) float64 metres in that frame.

Reference:
    Y. Chen, G. Medioni, "Object modelling by registration of multiple range images",
    Image and Vision Computing 10(3), 1992 (point-to-plane ICP).
"""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.common import invert_transform, transform_points
from tlessbot_ros.core.pose.buckets import PointBuckets
from tlessbot_ros.core.pose.candidates import PoseCandidate
from tlessbot_ros.core.pose.database import ObjectTemplates
from tlessbot_ros.core.pose.grid_kernels import (
    gauss_newton,
    inlier_fraction,
    keep_near_tangent_plane,
    self_visible,
    truncated_cost,
)
from tlessbot_ros.core.pose.params import PoseParams


def _rotation_translation(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, 4, 4) poses -> contiguous float64 (K, 3, 3) rotations and (K, 3) translations."""
    T = np.asarray(T, np.float64).reshape(-1, 4, 4)
    return np.ascontiguousarray(T[:, :3, :3]), np.ascontiguousarray(T[:, :3, 3])


class Refiner:
    """Point-to-plane refinement and scoring of pose hypotheses (see the module docstring).

    Uses ``params``' ``planar_iterations``, ``icp_iterations``, ``icp_distance_voxels``,
    ``icp_points``, ``inlier_voxels`` and ``inlier_plane_m``.

    Example:
        >>> refiner = Refiner(PoseParams())
        >>> T = refiner.icp(scene_c, database[5], T_start)
        >>> refiner.evaluate(scene_c, database[5], T, method='ransac').fitness
    """

    def __init__(self, params: PoseParams = PoseParams()):
        self.params = params

    # ---------------------------------------------------------------------------- scores
    def truncated_cost(self, T: np.ndarray, points: np.ndarray, obj: ObjectTemplates, *,
                       tau: float) -> np.ndarray:
        """(K,) mean distance of ``points`` to the model, each truncated at ``tau`` (m), for K
        poses, via the nearest-sample grid's distances."""
        grid = obj.nearest_grid()
        return truncated_cost(*_rotation_translation(T), np.ascontiguousarray(points, np.float64),
                              grid.origin, grid.spacing, grid.distance, tau)

    def grid_fitness(self, T: np.ndarray, points: np.ndarray, obj: ObjectTemplates
                     ) -> np.ndarray:
        """(K,) fraction of ``points`` within ``inlier_voxels`` of the model for K poses of the
        object in the points' frame, via the nearest-sample grid."""
        grid = obj.nearest_grid()
        _, model = obj.model_arrays_float64()
        return inlier_fraction(*_rotation_translation(T), np.ascontiguousarray(points),
                               grid.origin, grid.spacing, grid.index, model,
                               self.params.inlier_voxels * obj.voxel_size_m)

    # ------------------------------------------------------------------------ refinement
    def planar(self, T: np.ndarray, points_w: np.ndarray, obj: ObjectTemplates, *,
               tau: float) -> tuple[np.ndarray, np.ndarray]:
        """(yaw, x, y) point-to-plane Gauss-Newton of K poses ``T_world_object`` (table at
        world z = 0) at once on the nearest grid; returns the poses and their final truncated
        mean distance (tau)."""
        p = self.params
        grid = obj.nearest_grid()
        normals, model = obj.model_arrays_float64()
        points_w = np.ascontiguousarray(points_w, np.float64)
        half = p.planar_iterations // 2
        max_d = obj.voxel_size_m * np.where(np.arange(p.planar_iterations) < half, 4.0, 2.0)
        R, t = gauss_newton(*_rotation_translation(T), points_w, grid.origin, grid.spacing,
                            grid.index, model, normals, max_d, True, 0.0)
        T = np.array(T, np.float64).reshape(-1, 4, 4)
        T[:, :3, :3], T[:, :3, 3] = R, t
        return T, truncated_cost(*_rotation_translation(T), points_w, grid.origin,
                                 grid.spacing, grid.distance, tau)

    def icp(self, scene_c: np.ndarray, obj: ObjectTemplates, T_camera_object: np.ndarray,
            *, iterations: int | None = None) -> np.ndarray:
        """6-DOF point-to-plane ICP of the scene onto the model surface samples."""
        refined: np.ndarray = self.icp_batch(scene_c, obj, np.asarray(T_camera_object)[None],
                                             iterations=iterations)[0]
        return refined

    def icp_batch(self, scene_c: np.ndarray, obj: ObjectTemplates, T_camera_object: np.ndarray,
                  *, iterations: int | None = None, points: int | None = None,
                  distance_m: float | None = None) -> np.ndarray:
        """Point-to-plane ICP (Chen & Medioni 1992) of K (K, 4, 4) starting poses at once; the
        model's nearest sample comes from the nearest-sample grid (O(1) per point).
        ``iterations``, ``points`` (scene points used, evenly strided) and ``distance_m`` (the
        correspondence distance of the second half of the iterations; the first half uses
        twice that) default to ``icp_iterations``, ``icp_points`` and ``icp_distance_voxels``
        voxels."""
        p = self.params
        grid = obj.nearest_grid()
        normals, model = obj.model_arrays_float64()
        T = np.array(T_camera_object, np.float64).reshape(-1, 4, 4)
        points = p.icp_points if points is None else points
        if len(scene_c) > points:
            scene_c = scene_c[::int(np.ceil(len(scene_c) / points))]
        iterations = p.icp_iterations if iterations is None else iterations
        scene_c = np.ascontiguousarray(scene_c, np.float64)
        distance_m = p.icp_distance_voxels * obj.voxel_size_m if distance_m is None \
            else distance_m
        max_d = distance_m * np.where(np.arange(iterations) < iterations // 2, 2.0, 1.0)
        R, t = gauss_newton(*_rotation_translation(T), scene_c, grid.origin, grid.spacing,
                            grid.index, model, normals, max_d, False, 1e-6)
        T[:, :3, :3], T[:, :3, 3] = R, t
        return T

    # ------------------------------------------------------------------------ evaluation
    def evaluate(self, scene_c: np.ndarray, obj: ObjectTemplates, T_camera_object: np.ndarray,
                 *, method: str, stable: int = -1, template: int = -1,
                 scene_buckets: PointBuckets | None = None,
                 scene_depth_m: float | None = None) -> PoseCandidate:
        """Fitness / RMSE (scene -> model) and coverage (visible model -> scene).

        ``scene_buckets``: :class:`PointBuckets` of ``scene_c`` with an edge of at least
        :meth:`coverage_radius`; ``scene_depth_m``: the median z of ``scene_c`` (each built
        here when not given; a caller that evaluates several poses of one scene passes them).
        """
        inlier = self.params.inlier_voxels * obj.voxel_size_m
        q = transform_points(invert_transform(T_camera_object), scene_c)
        dist, index = obj.model_buckets(inlier).nearest(q, inlier)
        ok = np.isfinite(dist)
        if self.params.inlier_plane_m > 0 and ok.any():
            # ... and within inlier_plane_m of the tangent plane there: small features (a few
            # mm) decide between near-symmetric poses that a voxel-wide radius cannot tell apart
            normals_all, model_all = obj.model_arrays_float64()
            keep_near_tangent_plane(q, index, model_all, normals_all, self.params.inlier_plane_m,
                                    ok)
        fitness = float(ok.mean()) if len(ok) else 0.0
        rmse = float(np.sqrt(np.mean(dist[ok] ** 2))) if ok.any() else np.inf
        model, normals = obj.model_subset()
        model_c = model @ T_camera_object[:3, :3].T + T_camera_object[:3, 3]
        normals_c = normals @ T_camera_object[:3, :3].T
        if scene_depth_m is None:
            scene_depth_m = float(np.median(scene_c[:, 2]))
        visible = self_visible(model_c, normals_c, 0.5 * obj.voxel_size_m
                               / max(scene_depth_m, 1e-3), obj.voxel_size_m)
        coverage = 1.0
        if visible.any():
            radius = self.coverage_radius(obj)
            scene_buckets = scene_buckets or PointBuckets.build(scene_c, radius)
            coverage = float(scene_buckets.any_within(model_c[visible], radius).mean())
        return PoseCandidate(np.asarray(T_camera_object, np.float64), fitness, rmse, coverage,
                             method, template, stable)

    def surface_fit(self, scene_c: np.ndarray, obj: ObjectTemplates, T_camera_object: np.ndarray,
                    *, inlier_m: float) -> tuple[float, float]:
        """Fitness and RMSE of ``scene_c`` (N, 3) against the model at one absolute tolerance
        ``inlier_m`` (m), the same for every object: a point is an inlier when it lies within
        ``inlier_m`` of the tangent plane of its nearest model sample, searched within
        ``max(inlier_m, voxel)``. Returns (fitness, RMSE of the inliers' plane distances, m;
        inf without inliers).

        :meth:`evaluate` measures at the object's own voxel, so a large part (a coarse voxel)
        explains a small part's points better than the small part itself does: classes are
        compared here instead (:func:`~tlessbot_ros.core.part_fit.fit_part`). The plane
        distance does not depend on how densely the model is sampled."""
        if len(scene_c) == 0:
            return 0.0, np.inf
        plane = self.surface_distances(scene_c, obj, T_camera_object, reach_m=inlier_m)
        ok = plane <= inlier_m
        rmse = float(np.sqrt(np.mean(plane[ok] ** 2))) if ok.any() else np.inf
        return float(ok.mean()), rmse

    @staticmethod
    def surface_distances(scene_c: np.ndarray, obj: ObjectTemplates,
                          T_camera_object: np.ndarray, *, reach_m: float) -> np.ndarray:
        """(N,) distance (m) of each of ``scene_c`` (N, 3) from the tangent plane of its
        nearest model sample, searched within ``max(reach_m, voxel)`` (inf beyond)."""
        reach = max(float(reach_m), obj.voxel_size_m)
        q = transform_points(invert_transform(T_camera_object), scene_c)
        dist, index = obj.model_buckets(reach).nearest(q, reach)
        found = np.isfinite(dist)
        normals, model = obj.model_arrays_float64()
        plane = np.full(len(q), np.inf)
        j = index[found]
        plane[found] = np.abs(np.einsum('ij,ij->i', q[found] - model[j], normals[j]))
        return plane

    @staticmethod
    def coverage_radius(obj: ObjectTemplates) -> float:
        """A visible model sample is covered by a scene point within this distance (m)."""
        return 2.0 * obj.voxel_size_m
