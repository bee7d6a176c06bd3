"""One part's pose fit within a frame (stage 3 of :mod:`tlessbot_ros.core.pipeline`): its class
candidates fitted in order, the best kept (verification by geometry), then the look-alike check
on every view that sees it. A worker process runs :func:`fit_part` alone (it has no views)."""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from tlessbot_ros.core.common import transform_points
from tlessbot_ros.core.frame import Detection, PartJob
from tlessbot_ros.core.params import FitParams
from tlessbot_ros.core.pose import (
    LookalikeCheck,
    PoseCandidate,
    PoseEstimator,
    PoseResult,
    TemplateDatabase,
    inside_outline,
)
from tlessbot_ros.core.recognise import UNKNOWN_ID


def fit_part(estimator: PoseEstimator, params: FitParams, job: PartJob) -> None:
    """Fit one part's class candidates in order and keep the best (fills the detection's
    class, rank and poses); stop at the first whose fitness reaches
    ``verify_accept_fitness``.

    With several candidates and a table frame, each is fitted by the table path alone
    and unpolished (a wrong class fits poorly, and the fallback would spend its time on
    it; the polish, ``PoseParams.polish_iterations``, would let it converge as well as the
    right one): the fits name the class, then the winner's finalists alone are polished
    (:meth:`PoseEstimator.polish`) and the fallback runs once, for the winner, if its fit
    stays poor. The look-alike check comes after, in the pipeline's ``estimate_poses``
    (:func:`check_lookalike`).

    In box mode (``job.box``) the class is named as without a box (a larger class covers a
    box as well as the right one), then the winner's pose is searched again with it."""
    detection, points, T_world_camera = job.detection, job.points, job.T_world_camera
    quick = len(job.candidates) > 1 and T_world_camera is not None
    best_value, winner = None, None
    scenes: dict[float, np.ndarray] = {}   # the ROI prepared once per voxel edge
    sample = _verify_sample(points, params) if len(job.candidates) > 1 else points
    for rank, obj_id in enumerate(job.candidates):
        result = estimator.estimate(points, obj_id, T_world_camera=T_world_camera,
                                    fallback=False if quick else None,
                                    polish=False if quick else None, scenes=scenes,
                                    box=None if quick else job.box)
        if result.best is None:
            continue
        value = _verify_value(estimator, params, sample, obj_id, result.best)
        # another class overrules the classifier's first only by a clear margin
        margin = params.verify_overrule_margin if winner is not None and \
            detection.class_rank == 0 else 0.0
        shift = _twin_coverage(estimator, params, obj_id, result.best, winner)
        if best_value is None or value - shift > best_value + margin:
            best_value, winner = value, result
            detection.obj_id, detection.class_rank = obj_id, rank
        if rank == 0 and result.best.fitness >= params.verify_accept_fitness:
            break
    if winner is not None:
        if quick and job.box is not None:
            winner = estimator.estimate(points, detection.obj_id, T_world_camera=T_world_camera,
                                        fallback=False, scenes=scenes, box=job.box)
        elif quick:
            winner = estimator.polish(points, winner, scenes=scenes)
        detection.pose, detection.second = winner.best, winner.second
    pose_params = estimator.params
    if quick and detection.pose is not None and pose_params.fallback and \
            params.fallback_min_fitness <= detection.pose.fitness < pose_params.fallback_fitness:
        result = estimator.estimate(points, detection.obj_id, T_world_camera=T_world_camera,
                                    scenes=scenes, box=job.box)
        if result.best is not None and result.best.score > detection.pose.score:
            detection.pose, detection.second = result.best, result.second
    if detection.pose is not None and len(job.candidates) > 1 and \
            detection.pose.fitness < params.fit_rank_min_fitness:   # core/by_fit.py
        mark_unknown(detection, len(job.candidates))


def unknown_last(params: FitParams, jobs: Sequence[PartJob],
                 publish: Callable[[Detection], None],
                 estimator: PoseEstimator | None = None, *,
                 box_mode: bool = False) -> Callable[[Detection], None]:
    """``publish`` behind the last word on each of ``jobs``' parts, taken once the fragment
    check has kept it (so that it changes nothing else): a part whose best fit explains less
    than ``unknown_below_fitness`` of its depth points (:func:`explained_share`), whose
    fitted outline covers less than ``unknown_below_cover`` of its region's points (masks
    only: a box holds neighbours), or that got no pose with ``unknown_without_fit``, is
    reported unknown."""
    by_detection = {id(job.detection): job for job in jobs}
    cover = 0.0 if box_mode else params.unknown_below_cover

    def judged(detection: Detection) -> None:
        job, pose = by_detection[id(detection)], detection.pose
        if pose is None:
            unknown = params.unknown_without_fit
        else:
            share, covered = outline_shares(params, job.points, detection.obj_id, pose,
                                            estimator)
            unknown = share < params.unknown_below_fitness or covered < cover
        if unknown:
            mark_unknown(detection, len(job.candidates))
        publish(detection)
    return judged


def explained_share(params: FitParams, points: np.ndarray, obj_id: int, pose: PoseCandidate,
                    estimator: PoseEstimator | None = None) -> float:
    """The share of a part's ROI ``points`` that class ``obj_id`` at ``pose`` explains, as
    the unknown rule (:func:`unknown_last`) reads it: with ``estimator``, on the verification
    sample at ``verify_inlier_m`` (:func:`_verify_fitness`), else the pose's own fitness.
    With ``unknown_in_outline`` only the sample's points inside the posed model's outline
    count (:func:`~tlessbot_ros.core.pose.inside_outline`): a neighbour in the region's box
    is no evidence against the part, and a model that covers none of its points explains
    nothing (0)."""
    return outline_shares(params, points, obj_id, pose, estimator)[0]


def outline_shares(params: FitParams, points: np.ndarray, obj_id: int, pose: PoseCandidate,
                   estimator: PoseEstimator | None = None) -> tuple[float, float]:
    """(:func:`explained_share`, the share of the verification sample of ``points`` inside
    the posed model's outline; 1 where the outline is not read)."""
    if estimator is None:
        return float(pose.fitness), 1.0
    sample = _verify_sample(points, params)
    covered = 1.0
    if params.unknown_in_outline and params.verify_inlier_m > 0 and len(sample):
        obj = estimator.database[obj_id]
        model_c = transform_points(pose.T_camera_object, obj.model_points)
        inside = inside_outline(sample, model_c, obj.sample_spacing_m())
        sample, covered = sample[inside], float(inside.mean())
        if len(sample) == 0:
            return 0.0, covered
    return float(_verify_fitness(estimator, params, sample, obj_id, pose)), covered


def mark_unknown(detection: Detection, rank: int) -> None:
    """Report ``detection`` as an unknown part (no class, no pose); ``rank``: past its
    candidates."""
    detection.obj_id, detection.class_rank = UNKNOWN_ID, rank
    detection.pose = detection.second = None


def _verify_sample(points: np.ndarray, params: FitParams) -> np.ndarray:
    """The ROI points every class candidate is scored on, evenly strided to at most
    ``verify_points``."""
    points = np.asarray(points, np.float64)
    if len(points) > params.verify_points:
        points = points[::int(np.ceil(len(points) / params.verify_points))]
    return points


def _verify_fitness(estimator: PoseEstimator, params: FitParams, sample: np.ndarray,
                    obj_id: int, best: PoseCandidate) -> float:
    """The share of ``sample`` that class ``obj_id`` at ``best`` explains, at
    ``verify_inlier_m`` (:meth:`~tlessbot_ros.core.pose.Refiner.surface_fit`; the pose's own
    fitness when that is 0)."""
    if params.verify_inlier_m <= 0:
        return best.fitness
    return estimator.refiner.surface_fit(sample, estimator.database[obj_id],
                                         best.T_camera_object,
                                         inlier_m=params.verify_inlier_m)[0]


def _twin_coverage(estimator: PoseEstimator, params: FitParams, obj_id: int,
                   best: PoseCandidate, winner: PoseResult | None) -> float:
    """``fit_rank_coverage_weight`` x (the coverage of class ``obj_id`` at ``best`` - the
    current ``winner``'s) when the two are listed look-alikes, else 0: twins share one outline,
    so their coverages differ by noise, which must not break their tie (the classifier's
    order does, and the look-alike checks after the fit)."""
    if winner is None or winner.best is None or params.fit_rank_coverage_weight == 0 or \
            winner.obj_id not in estimator.database[obj_id].lookalikes:
        return 0.0
    return params.fit_rank_coverage_weight * (best.coverage - winner.best.coverage)


def _verify_value(estimator: PoseEstimator, params: FitParams, sample: np.ndarray, obj_id: int,
                  best: PoseCandidate) -> float:
    """How well class ``obj_id`` at its fitted pose ``best`` explains the ROI: fitness -
    ``verify_rmse_weight`` * RMSE + ``fit_rank_coverage_weight`` * coverage; with
    ``verify_inlier_m`` > 0 the fitness and RMSE are taken on ``sample`` at that one tolerance
    for every class (:meth:`~tlessbot_ros.core.pose.Refiner.surface_fit`), else at the class's
    own voxel (its pose score)."""
    fitness, rmse = best.fitness, best.inlier_rmse_m
    if params.verify_inlier_m > 0:
        fitness, rmse = estimator.refiner.surface_fit(
            sample, estimator.database[obj_id], best.T_camera_object,
            inlier_m=params.verify_inlier_m)
    rmse = rmse if np.isfinite(rmse) else 0.0
    return float(fitness - params.verify_rmse_weight * rmse
                 + params.fit_rank_coverage_weight * best.coverage)


def check_lookalike(lookalike: LookalikeCheck | None, job: PartJob, *,
                    refine: bool | Callable[[], bool] = False) -> None:
    """A fitted part whose class has a look-alike is compared with it at the fitted pose,
    on the depth of its view and of ``job.more_views`` (``lookalike_*``); the look-alike
    names the part when it explains that depth better by a clear margin (``refine``: each
    from its own pose near the fit, :meth:`~tlessbot_ros.core.pose.LookalikeCheck.resolve`)."""
    detection = job.detection
    if lookalike is None or detection.pose is None or detection.obj_id not in lookalike:
        return
    winner, _ = lookalike.resolve(detection.obj_id, detection.pose.T_camera_object,
                                  job.points, more_views=job.more_views,
                                  T_world_camera=job.T_world_camera, refine=refine)
    if winner != detection.obj_id:
        # the twins share their model frame, so the fitted pose is the twin's too
        detection.obj_id = winner
        detection.class_rank = job.candidates.index(winner) \
            if winner in job.candidates else len(job.candidates)


def flat_parts(database: TemplateDatabase, fit: FitParams) -> frozenset[int]:
    """The ids of the parts the flat parts' orientation check turns over (``flat``: on, the
    part flat and its mesh kept); their depth in the other views is gathered for it."""
    from tlessbot_ros.core.pose.flat_params import is_flat

    if not fit.flat.enabled:
        return frozenset()
    return frozenset(i for i, o in database.objects.items()
                     if o.mesh_faces is not None and is_flat(o, fit.flat.flat_ratio))


def lookalike_check(database: TemplateDatabase, fit: FitParams) -> LookalikeCheck | None:
    """The look-alike check ``fit``'s ``lookalike_*`` ask for (None when it is off)."""
    if not fit.lookalike_check:
        return None
    return database.lookalike_check(tolerance_m=fit.lookalike_tolerance_m,
                                    min_z=fit.lookalike_min_z)


def depth_checks(database: TemplateDatabase, fit: FitParams
                 ) -> tuple[LookalikeCheck | None, frozenset[int]]:
    """The look-alike check ``fit`` asks for (None when off) and the ids of the flat parts
    (:func:`flat_parts`)."""
    return lookalike_check(database, fit), flat_parts(database, fit)


def warm_up_checks(database: TemplateDatabase, lookalike: LookalikeCheck | None,
                   flat_ids: frozenset[int] = frozenset()) -> None:
    """Build the ray-casting scenes of the look-alike check (when on) and of the flat parts
    now, and cast a ray into each (Open3D builds the BVH at the first query)."""
    from tlessbot_ros.core.pose.flat_turns import mesh_scene
    from tlessbot_ros.core.pose.lookalike import depth_errors

    if lookalike is not None:
        lookalike.warm_up()
    for obj_id in flat_ids:
        scene = mesh_scene(database[obj_id])
        if scene is not None:
            depth_errors(scene, np.eye(4), np.array([[0.0, 0.0, 1.0]]))


def lookalike_options(fit: FitParams) -> tuple[object, ...]:
    """The fields of ``fit`` the look-alike check and the flat parts' ids are built with."""
    return fit.lookalike_check, fit.lookalike_tolerance_m, fit.lookalike_min_z, fit.flat


def pose_stage(estimator: PoseEstimator | None) -> PoseEstimator:
    """``estimator``; a pipeline without templates has none to fit with."""
    if estimator is None:
        raise ValueError('no template database loaded')
    return estimator


__all__ = ['check_lookalike', 'depth_checks', 'explained_share', 'fit_part', 'flat_parts',
           'lookalike_check', 'lookalike_options', 'mark_unknown', 'outline_shares', 'pose_stage',
           'unknown_last', 'warm_up_checks']
