"""Flat parts in the composed pipeline: the orientation check of a fitted part over every view.

:func:`check_flat` gathers what each camera shows of a fitted part (colour, the localiser's
label, the rig's transform from the fitted view; the part's depth in the other views) and lets
:class:`~tlessbot_ros.core.pose.FlatCheck` turn a flat part over when the image or the depth
shows the other face up.
"""
from __future__ import annotations

from dataclasses import replace
from functools import partial
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.pose.flat import FlatCheck, FlatParams, ViewEvidence
from tlessbot_ros.core.pose.flat_turns import level_on_table, mesh_scene, refine_yaw
from tlessbot_ros.core.pose.flat_yaw import hole_yaw, hole_yaw_period

if TYPE_CHECKING:
    from collections.abc import Sequence

    import open3d as o3d

    from tlessbot_ros.core.frame import Detection, PartJob, ViewInput
    from tlessbot_ros.core.pipeline import PerceptionPipeline
    from tlessbot_ros.core.pose.database import ObjectTemplates


def check_fitted_part(pipeline: PerceptionPipeline, job: PartJob,
                      views: dict[str, ViewInput], labels: dict[str, np.ndarray]) -> None:
    """The checks of a fitted part that read every view (so the pipeline runs them, not a
    worker): the flat parts' orientation check (:func:`check_flat`), the depth's look-alike
    check (:meth:`PerceptionPipeline.check_lookalike`), then the twins on the image
    (:func:`check_twins`). A part with look-alikes is named first on the image's edges
    (:func:`twins_on_edges`); the depth's checks name it where the edges leave it open."""
    info = check_flat(pipeline, job, views, labels)
    if twins_on_edges(pipeline, job, views, labels):
        return   # a hole's rim or a mirrored crease on the image: the depth may have lost it
    if info is not None and info.get('align_decided'):
        return   # the aligned votes of every view named the part among its twins too
    # asked only where the fitted pose leaves the twins open: most parts never need it
    pipeline.check_lookalike(job, refine=partial(refine_twins, pipeline, job, views, labels)
                             if pipeline.fit_params.lookalike_refine else False)
    check_twins(pipeline, job, views, labels)


def colour_views(views: dict[str, ViewInput], labels: dict[str, np.ndarray], instance: int,
                 fit_view: str, tables: dict[str, np.ndarray | None] | None = None
                 ) -> list[ViewEvidence]:
    """The :class:`ViewEvidence` of part ``instance`` fitted in ``fit_view``: that view, and
    every other view with colour (or, with ``tables``, depth), the part's label and rig
    extrinsics for both. ``tables``: per view its table frame ``T_world_camera`` (or None),
    for the aligned votes (the view's depth, table plane and the other parts' labels)."""
    from tlessbot_ros.core.common import plane_of_frame

    out = []
    T_fit = views[fit_view].T_world_camera
    for name, view in views.items():
        T_table = (tables or {}).get(name)
        if name not in labels or (view.rgb is None and T_table is None):
            continue
        if name == fit_view:
            T_view_fit = np.eye(4)
        elif T_fit is None or view.T_world_camera is None:
            continue
        else:
            T_view_fit = np.linalg.inv(view.T_world_camera) @ T_fit
        label = labels[name]
        if T_table is None:
            out.append(ViewEvidence(view.rgb, label == instance, view.intrinsics, T_view_fit))
            continue
        out.append(ViewEvidence(view.rgb, label == instance, view.intrinsics, T_view_fit,
                                view.depth_m, plane_of_frame(T_table),
                                (label != 0) & (label != instance)))
    return out


def check_flat(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
               labels: dict[str, np.ndarray]) -> dict[str, float] | None:
    """Turn ``job``'s fitted flat part over when the image shows the other face up, check its
    yaw on the image, then let the depth of its views turn it over
    (:class:`~tlessbot_ros.core.pose.FlatCheck`, ``FitParams.flat``); the former pose becomes
    the detection's ``second``. The yaw is searched last on the aligned score
    (:func:`~tlessbot_ros.core.pose.flat_yaw.hole_yaw`): a round part's within its period (its
    silhouette holds no yaw, so it skips the silhouette's check), another's lying on a face
    within a few degrees. Returns what decided (None when the part is not checked)."""
    detection = job.detection
    estimator = pipeline.pose_estimator
    if estimator is None or detection.pose is None or job.T_world_camera is None:
        return None
    database = estimator.database
    obj = database[detection.obj_id]
    check = flat_check(pipeline)
    if not check.applies(obj):
        return None
    evidence = colour_views(views, labels, detection.instance_id, detection.view,
                            table_frames(pipeline, views))
    info: dict[str, float] = {}
    up_c = np.linalg.inv(job.T_world_camera)[:3, 2]   # the table's normal, camera frame
    round_part = False   # a round outline with holes: only the holes tell its yaw
    if evidence:
        if yaw_search_mesh(obj, evidence, check.params) is not None and \
                hole_yaw_period(obj) <= 0:
            # the aligned round compares exact half turns of the fit, which inherit its yaw:
            # the outline's yaw (the same for either face) is checked first
            first, info['first_yaw_deg'] = refine_yaw(
                check, obj, detection.pose.T_camera_object, job.T_world_camera, evidence)
            detection.pose = replace(detection.pose, T_camera_object=first)
        twins = [database[i] for i in obj.lookalikes if i in database]
        T, turned = check.resolve(obj, detection.pose.T_camera_object, job.points,
                                  job.T_world_camera, evidence, twins)
        info.update(turned)
        if info.get('align_decided') and int(info['twin']) != detection.obj_id:
            rename(detection, job, int(info['twin']))
            obj = database[detection.obj_id]
        if T is not None:
            detection.turned_over = True
            detection.second = detection.pose
            detection.pose = replace(detection.pose, T_camera_object=T,
                                     fitness=info['flip_fitness'])
        round_part = hole_yaw_period(obj) > 0 and \
            yaw_search_mesh(obj, evidence, check.params) is not None
        if not round_part:
            T, info['yaw_deg'] = refine_yaw(check, obj, detection.pose.T_camera_object,
                                            job.T_world_camera, evidence)
            detection.pose = replace(detection.pose, T_camera_object=T)
    if not info.get('align_decided'):   # else the aligned votes of every view decided it
        T, info['depth_turn_vote'] = check.depth_turn(obj, detection.pose.T_camera_object,
                                                      job.points, job.more_views,
                                                      job.T_world_camera)
        if T is not None and not check.ranked_lower(detection.pose.T_camera_object, T):
            detection.turned_over = not detection.turned_over
            detection.second = detection.pose
            detection.pose = replace(detection.pose, T_camera_object=T)
    mesh = yaw_search_mesh(obj, evidence, check.params)
    if mesh is not None:
        T, info['hole_yaw_deg'] = hole_yaw(obj, mesh, detection.pose.T_camera_object,
                                           evidence, check.params, up_c)
        detection.pose = replace(detection.pose, T_camera_object=T)
    T = level_on_table(detection.pose.T_camera_object, obj.model_points.astype(np.float64),
                       up_c, pipeline.fit_params.flat.depth_tolerance_m)
    if T is not None:
        detection.pose = replace(detection.pose, T_camera_object=T)
    info['levelled'] = float(T is not None)
    return info


def flat_check(pipeline: PerceptionPipeline) -> FlatCheck:
    """The pipeline's :class:`~tlessbot_ros.core.pose.FlatCheck`: its refiner, ``flat``
    settings and the ROI cloud's preparation (voxel scale, outlier removal) as the fit had it
    (the pipeline must have a pose estimator)."""
    estimator = pipeline.pose_estimator
    assert estimator is not None
    cloud = estimator.params.cloud
    return FlatCheck(estimator.refiner, pipeline.fit_params.flat,
                     voxel_scale=estimator.params.table_voxel_scale,
                     sor_neighbors=cloud.sor_neighbors, sor_std_ratio=cloud.sor_std_ratio)


def yaw_search_mesh(obj: ObjectTemplates, evidence: Sequence[ViewEvidence], params: FlatParams
                    ) -> o3d.t.geometry.RaycastingScene | None:
    """``obj``'s ray-casting scene when its yaw is searched on the aligned score
    (:func:`~tlessbot_ros.core.pose.flat_yaw.hole_yaw`: yaw steps on, a mesh, a view with a
    table frame), else None."""
    if params.yaw_steps < 1 or not any(view.plane is not None for view in evidence):
        return None
    return mesh_scene(obj)


def check_twins(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                labels: dict[str, np.ndarray]) -> dict[str, float] | None:
    """A fitted flat part with a look-alike (one hole more, say) is named by what its views
    show at the fitted pose (look-alikes share their model frame): with a table frame, both
    meshes are compared on the aligned height and colour votes of every view
    (:func:`~tlessbot_ros.core.pose.flat_align.view_votes`) and the winner of their duels
    names the part when it beats every other by a clear margin (``flat.align_min_z``); without
    one, on the colour image alone (:func:`_twins_on_colour`). Returns what decided (None: not
    checked)."""
    from tlessbot_ros.core.common import raycasting_scene
    from tlessbot_ros.core.pose.flat_align import round_robin, view_votes
    from tlessbot_ros.core.pose.lookalike import clear_margin

    detection = job.detection
    estimator = pipeline.pose_estimator
    params = pipeline.fit_params.flat
    if estimator is None or detection.pose is None or not params.enabled:
        return None
    database = estimator.database
    obj = database[detection.obj_id]
    twins = [database[i] for i in obj.lookalikes if i in database]
    if not twins or obj.mesh_faces is None or not FlatCheck(
            estimator.refiner, params).applies(obj):
        return None
    parts = [obj] + [t for t in twins if t.mesh_faces is not None]
    scenes = [p.derived('raycasting', partial(raycasting_scene, vertices, faces))
              for p in parts if (faces := p.mesh_faces) is not None
              and (vertices := p.mesh_vertices) is not None]   # all of them
    evidence = colour_views(views, labels, detection.instance_id, detection.view,
                            table_frames(pipeline, views))
    if any(view.plane is not None for view in evidence):
        T = detection.pose.T_camera_object
        votes = view_votes(scenes, [T] * len(parts), obj.model_points.astype(np.float64),
                           evidence, align_at_1m_m=params.align_at_1m_m,
                           tolerance_m=params.depth_tolerance_m)
        k = round_robin(votes)
        decided = all(clear_margin(int(votes[k, j]), int(votes[j, k]), params.align_min_z)
                      for j in range(len(parts)) if j != k)
        info = {'twin': float(parts[k].obj_id), 'twin_decided': float(decided)}
        k = k if decided else 0
    else:
        k, info = _twins_on_colour(parts, scenes, detection.pose.T_camera_object, evidence,
                                   params)
    if k > 0:
        rename(detection, job, parts[k].obj_id)
    return info


def twins_on_edges(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                   labels: dict[str, np.ndarray]) -> bool:
    """Name a fitted part among its look-alikes by the colour image's edges: each look-alike's
    mesh drawn at the fitted pose (they share their model frame), its edges inside the outline
    laid on the image's (:func:`~tlessbot_ros.core.pose.image_edges.candidate_edge_votes`).
    The winner of their duels names the part when it beats every other by a clear margin
    (``FitParams.lookalike_edge_min_z``). Returns whether the edges decided.

    A feature that tells twins apart (a 6 mm hole, a mirrored crease) is a few pixels wide: a
    smoothed, stereo-like depth fills it, and the depth then votes for the twin without it; its
    rim stays an edge in the image. A twin's hole where the image shows the face votes against
    that twin (``FitParams.lookalike_shut_holes``)."""
    from tlessbot_ros.core.pose.flat_align import round_robin
    from tlessbot_ros.core.pose.image_edges import candidate_edge_votes, flat_edge_settings
    from tlessbot_ros.core.pose.lookalike import clear_margin

    detection, check = job.detection, pipeline.lookalike
    min_z = pipeline.fit_params.lookalike_edge_min_z
    estimator = pipeline.pose_estimator
    if check is None or estimator is None or detection.pose is None or min_z <= 0 or \
            detection.obj_id not in check:
        return False
    evidence = [view for view in colour_views(views, labels, detection.instance_id,
                                              detection.view, table_frames(pipeline, views))
                if view.rgb is not None]
    if not evidence:
        return False
    ids = (detection.obj_id, *check.lookalikes[detection.obj_id])
    points_o = np.concatenate([estimator.database[i].model_points for i in ids])
    T = detection.pose.T_camera_object
    shut_holes = pipeline.fit_params.lookalike_shut_holes
    votes = candidate_edge_votes([(check.scene(i), T) for i in ids], points_o.astype(np.float64),
                                 evidence, shut_hole_votes=shut_holes,
                                 **flat_edge_settings(pipeline.fit_params.flat))  # type: ignore[arg-type]
    k = round_robin(votes)
    if not all(clear_margin(int(votes[k, j]), int(votes[j, k]), min_z)
               for j in range(len(ids)) if j != k):
        return False
    if k > 0:
        rename(detection, job, ids[k])
    return True


def refine_twins(pipeline: PerceptionPipeline, job: PartJob, views: dict[str, ViewInput],
                 labels: dict[str, np.ndarray]) -> bool:
    """Whether the depth's look-alike check (with ``FitParams.lookalike_refine``) may move
    each twin to its own pose and vote again: only where the depth at the fit measures per-pixel
    (:func:`~tlessbot_ros.core.pose.half_turns.measures_smoothed`). The refinement aligns
    the twins' few-millimetre holes on the pixels that see through the part, which a
    stereo-like depth fills."""
    from tlessbot_ros.core.pose.half_turns import measures_smoothed

    detection, check = job.detection, pipeline.lookalike
    estimator = pipeline.pose_estimator
    if check is None or estimator is None or detection.pose is None or \
            detection.obj_id not in check:
        return False
    evidence = colour_views(views, labels, detection.instance_id, detection.view,
                            table_frames(pipeline, views))
    return not measures_smoothed(flat_check(pipeline), estimator.database[detection.obj_id],
                                 check.scene(detection.obj_id),
                                 detection.pose.T_camera_object, evidence)


def rename(detection: Detection, job: PartJob, obj_id: int) -> None:
    """Name ``detection`` ``obj_id`` (a look-alike of its class: same model frame, so its
    pose stays), its class rank that id's among the job's candidates."""
    detection.obj_id = obj_id
    detection.class_rank = job.candidates.index(obj_id) if obj_id in job.candidates \
        else len(job.candidates)


def _twins_on_colour(parts: Sequence[ObjectTemplates],
                     scenes: Sequence[o3d.t.geometry.RaycastingScene], T_camera_object: np.ndarray,
                     evidence: list[ViewEvidence], params: FlatParams
                     ) -> tuple[int, dict[str, float]]:
    """The twin (index in ``parts``, 0: the part itself) that the colour image names, with
    what decided: the silhouettes of both meshes compared where they differ
    (:func:`~tlessbot_ros.core.pose.silhouette.disputed_votes`); a twin wins when more than
    ``min_share`` of at least ``min_disputed_px`` such pixels vote for it."""
    from tlessbot_ros.core.pose.silhouette import disputed_votes, mesh_silhouette, window

    votes = np.zeros((len(parts), 2))
    for view in evidence:
        if view.rgb is None:
            continue
        T = view.T_view_fit @ T_camera_object
        box = window(parts[0].model_points.astype(np.float64), [T], view.intrinsics,
                     margin_px=8)
        if box is None:
            continue
        x0, y0, w, h = box
        masks = [mesh_silhouette(scene, T, view.intrinsics, box) for scene in scenes]
        for k in range(1, len(parts)):
            votes[k] += disputed_votes(masks[0], masks[k], view.rgb[y0:y0 + h, x0:x0 + w])
    total = votes.sum(axis=1)
    share = np.where(total > 0, votes[:, 1] / np.maximum(total, 1), 0.0)
    k = int(np.argmax(share))
    info = {'twin': float(parts[k].obj_id), 'twin_share': float(share[k]),
            'disputed_px': float(total[k])}
    decided = k > 0 and total[k] >= params.min_disputed_px and share[k] > params.min_share
    return (k if decided else 0), info


def table_frames(pipeline: PerceptionPipeline, views: dict[str, ViewInput]
                 ) -> dict[str, np.ndarray | None]:
    """Each view with depth: its table frame ``T_world_camera`` (None where it has none)."""
    return {name: pipeline.table_frame(name, view).T_world_camera
            for name, view in views.items() if view.depth_m is not None}
