"""The paper's pose path (§3.3, §6.2), improved: FPFH + sample-consensus initial alignment.

:func:`register_templates` aligns each template of the recognised class to the ROI cloud
(Open3D RANSAC on FPFH feature matches, mutual filter, edge-length and distance checkers);
:func:`ransac_candidates` computes the scene features, registers the templates and refines the
best few with point-to-plane ICP against the CAD surface
(:class:`~tlessbot_ros.core.pose.refinement.Refiner`). The estimator runs it for
``method='ransac'`` and as the table path's former fallback (``fallback_method='templates'``;
the default fallback is :mod:`tlessbot_ros.core.pose.fallback`).

References:
    R. B. Rusu, N. Blodow, M. Beetz, "Fast Point Feature Histograms (FPFH) for 3D
    Registration", ICRA 2009 (FPFH, SAC-IA).
"""
from __future__ import annotations

import time

import numpy as np
import open3d as o3d

from tlessbot_ros.core.pose.candidates import PoseCandidate
from tlessbot_ros.core.pose.cloud import compute_fpfh, estimate_normals, to_o3d
from tlessbot_ros.core.pose.database import ObjectTemplates
from tlessbot_ros.core.pose.params import PoseParams
from tlessbot_ros.core.pose.refinement import Refiner


def _scene_features(scene_c: np.ndarray, obj: ObjectTemplates, params: PoseParams
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Normals (N, 3) and FPFH (N, 33) of the voxelised scene, with the templates' support."""
    p = params
    voxel = obj.voxel_size_m
    normals = estimate_normals(scene_c, radius_m=p.cloud.normal_radius_voxels * voxel,
                               max_nn=p.cloud.normal_max_nn)
    fpfh = compute_fpfh(scene_c, normals, radius_m=p.fpfh_radius_voxels * voxel,
                        max_nn=p.fpfh_max_nn)
    return normals, fpfh


def ransac_candidates(scene_c: np.ndarray, obj: ObjectTemplates, timings: dict[str, float], *,
                      params: PoseParams, refiner: Refiner,
                      indices: list[int] | None = None, max_iteration: int | None = None,
                      deadline: float | None = None) -> list[PoseCandidate]:
    """RANSAC candidates of one object in a voxelised scene cloud, refined and evaluated.

    Args:
        scene_c: (N, 3) voxelised scene points (camera frame), metres.
        obj: the object's templates.
        timings: gets ``'features'``, the scene features' time in ms.
        params: the RANSAC, FPFH and candidate settings.
        refiner: ICP and evaluation of the best ``params.ransac_candidates`` registrations
            (unused with ``params.refine`` off: then every template's registration is returned
            with coverage 0, ranked by RANSAC fitness alone as in the paper).
        indices, max_iteration, deadline: as :func:`register_templates`.

    Returns:
        unranked candidates (method 'ransac').
    """
    p = params
    t0 = time.perf_counter()
    normals, fpfh = _scene_features(scene_c, obj, p)
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
        T = refiner.icp(scene_c, obj, c.T_camera_object)
        out.append(refiner.evaluate(scene_c, obj, T, method='ransac',
                                    template=c.template_index))
    return out


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
    out: list[PoseCandidate] = []
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
