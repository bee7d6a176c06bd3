"""The perception stages composed over the label images the nodes exchange.

Stages (each a method, each usable alone, so the ROS nodes and the evaluator run the same code):

1. :meth:`PerceptionPipeline.localise`: segment every view, fuse them -> instance label images
   (uint16, same id for the same part in both views).
2. :meth:`PerceptionPipeline.classify`: HOG (+ shape) + linear model on each instance's crop
   in every view that sees it, scores summed over the views -> {instance: ClassGuess} with the
   best ``class_candidates`` classes.
3. :meth:`PerceptionPipeline.estimate_poses`: ROI cloud of each classified instance on the
   aligned depth of its preferred view (side when visible there, else top) -> pose in that
   camera's optical frame. Several candidate classes are verified by their fit (the first kept
   at fitness >= ``verify_accept_fitness``: near-identical T-LESS parts differ by millimetres a
   60 px crop cannot show); a look-alike is compared with its twin on the depth of every view
   (:mod:`.pose.lookalike`), a near-symmetric part with its turns on the colour image.

Inputs per view are :class:`ViewInput`; a two-view frame is ``{'top': ..., 'side': ...}``.

Every stage reads heights in a table frame (world z = 0 the table, z up): the view's
``T_world_camera`` from the rig, or the table plane found in its own depth
(:mod:`tlessbot_ros.core.common.table_plane`), as ``FitParams.table_plane`` says
(:meth:`PerceptionPipeline.table_frame`). So one RGB-D view without extrinsics still takes the
pose stage's fast table path.

What a frame takes and gives: :mod:`tlessbot_ros.core.frame`; the label images' per-view
bookkeeping: :mod:`tlessbot_ros.core.label_views`; one part's fit: :mod:`.part_fit`.
"""
from __future__ import annotations

import copy
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from tlessbot_ros.core.by_fit import fit_ranked, ranking_depth
from tlessbot_ros.core.colour_rim import trim_after_fits
from tlessbot_ros.core.common import (
    CAMERA_NAMES,
    SIDE,
    TOP,
    Rig,
    TableFrame,
    TablePlaneParams,
    TablePlaneTracker,
    above_table,
    choose_table_frame,
    find_table_plane,
    plane_of_frame,
)
from tlessbot_ros.core.flat_parts import check_fitted_part
from tlessbot_ros.core.frame import (
    ClassGuess,
    Detection,
    FrameResult,
    PartFitter,
    PartJob,
    ViewInput,
)
from tlessbot_ros.core.label_views import (
    PREFERRED_VIEWS,
    instance_ids,
    label_box,
    label_counts,
    label_stats,
    mask_in_box,
    preferred_view,
    second_view_thread,
    view_order,
)
from tlessbot_ros.core.localise import (
    FusionParams,
    FusionResult,
    Segmentation,
    SegmentationParams,
    fuse_views,
    segment,
    single_view,
    view_segmentation,
)
from tlessbot_ros.core.one_part import fitted_centre, join_pieces, one_part_filter
from tlessbot_ros.core.params import ClassifyParams, FitParams, LocaliseParams
from tlessbot_ros.core.part_fit import (
    check_lookalike,
    depth_checks,
    fit_part,
    lookalike_options,
    mark_unknown,
    pose_stage,
    unknown_last,
    warm_up_checks,
)
from tlessbot_ros.core.piece_union import touch_test, union_joiner
from tlessbot_ros.core.pose import (
    PoseEstimator,
    PoseParams,
    TemplateDatabase,
    drop_steep,
    roi_cloud,
)
from tlessbot_ros.core.recognise import UNKNOWN_ID, Classifier
from tlessbot_ros.core.refit_halves import split_or_refit
from tlessbot_ros.core.resting_check import check_resting_and_turns
from tlessbot_ros.core.turn_check import warm_up_turns

_REPLACEABLE = frozenset({'rig', 'classifier', 'localise_params', 'classify_params',
                          'fit_params', 'segmentation', 'fusion', 'pose', 'part_extents_m'})


class PerceptionPipeline:
    """Localiser, classifier and pose estimator with shared parameters.

    Args:
        rig: calibrated cameras (needed for two-view fusion beyond 'side_only').
        classifier: a trained :class:`~tlessbot_ros.core.recognise.Classifier` (needed by
            :meth:`classify`).
        templates: a :class:`TemplateDatabase` (needed by :meth:`estimate_poses`).
        localise_params, classify_params, fit_params: the options of each stage
            (:mod:`tlessbot_ros.core.params`).
        table_plane: how the table plane is found in each view's depth and tracked
            (``fit_params.table_plane`` says whether it is used).
        part_extents_m: (N, 3) the parts' box extents (m) that size each view's segmentation
            (:mod:`~tlessbot_ros.core.localise.part_scale`); None: the templates' parts.
    """

    def __init__(self, *, rig: Rig | None = None, classifier: Classifier | None = None,
                 templates: TemplateDatabase | None = None,
                 localise_params: LocaliseParams = LocaliseParams(),
                 classify_params: ClassifyParams = ClassifyParams(),
                 fit_params: FitParams = FitParams(),
                 segmentation: SegmentationParams = SegmentationParams(),
                 fusion: FusionParams = FusionParams(),
                 pose: PoseParams = PoseParams(),
                 table_plane: TablePlaneParams = TablePlaneParams(),
                 part_extents_m: np.ndarray | None = None) -> None:
        self.rig = rig
        self.part_extents_m = part_extents_m if part_extents_m is not None or templates is None \
            else templates.extents_m()
        self.classifier = classifier
        self.localise_params = localise_params
        self.classify_params = classify_params
        self.fit_params = fit_params
        self.segmentation = segmentation
        self.fusion = fusion
        self.table_plane = table_plane
        self._table_trackers: dict[str, TablePlaneTracker] = {}
        # per view: (the depth and extrinsics it was found for, its frame)
        self._tables: dict[str, tuple[tuple[object, object], TableFrame]] = {}
        self.pose_estimator = PoseEstimator(templates, params=pose) if templates else None
        self.lookalike, self.flat_ids = depth_checks(templates, fit_params) if templates else \
            (None, frozenset())

    def replace(self, **changes: Any) -> PerceptionPipeline:
        """A pipeline like this one with some of the constructor's arguments changed
        (``rig``, ``classifier``, and the ``*_params`` / ``segmentation`` / ``fusion`` /
        ``pose`` settings), like ``dataclasses.replace``. What the changes do not touch is
        shared, not rebuilt: the template database and its caches, the classifier, the
        look-alike and flat checks unless ``lookalike_*`` or ``flat`` changed (new ones are
        warmed up here).

        Raises:
            TypeError: an argument the constructor does not take (or ``templates``).
        """
        if unknown := set(changes) - _REPLACEABLE:
            raise TypeError(f'PerceptionPipeline.replace: cannot replace {sorted(unknown)}')
        new = copy.copy(self)
        for name, value in changes.items():
            if name != 'pose':
                setattr(new, name, value)
        if 'pose' in changes and self.pose_estimator is not None:
            new.pose_estimator = PoseEstimator(self.pose_estimator.database,
                                               params=changes['pose'])
        old, fit = self.fit_params, new.fit_params
        if self.pose_estimator is not None and lookalike_options(old) != lookalike_options(fit):
            new.lookalike, new.flat_ids = depth_checks(self.pose_estimator.database, fit)
            warm_up_checks(self.pose_estimator.database, new.lookalike, new.flat_ids)
        return new

    def warm_up(self, *, colour: bool = True) -> None:
        """Build the pose stage's caches (the turns' only for ``colour``): no slow 1st frame."""
        if self.pose_estimator is not None:
            self.pose_estimator.warm_up()
            warm_up_checks(self.pose_estimator.database, self.lookalike, self.flat_ids)
            warm_up_turns(self.pose_estimator.database, self.fit_params, colour=colour)
        if self.fit_params.table_plane != 'rig':   # compiles the plane search's loop
            flat = np.full((48, 64), 0.5, np.float32)
            find_table_plane(flat, np.array([[50.0, 0, 32], [0, 50.0, 24], [0, 0, 1]]),
                             params=self.table_plane)

    # ------------------------------------------------------------------------ table frame
    def table_frame(self, name: str, view: ViewInput) -> TableFrame:
        """The table frame view ``name`` is read in, as ``fit_params.table_plane`` says.

        Unless that is 'rig', the table plane is found in the view's depth (the rig's plane,
        when given, says which surface is the table) and tracked over frames (one tracker
        per view name: a fixed camera); the stages of one frame share it (found once per
        depth image). The result also says how far the rig's table is from the observed one.
        """
        key = (view.depth_m, view.T_world_camera)
        cached = self._tables.get(name)
        if cached is not None and cached[0][0] is key[0] and cached[0][1] is key[1]:
            return cached[1]
        p = self.fit_params
        observed, find_ms = None, 0.0
        if p.table_plane != 'rig' and view.depth_m is not None:
            t0 = time.perf_counter()
            prior = None if view.T_world_camera is None else plane_of_frame(view.T_world_camera)
            found = find_table_plane(view.depth_m, view.intrinsics.K, params=self.table_plane,
                                     prior=prior)
            tracker = self._table_trackers.setdefault(name, TablePlaneTracker(self.table_plane))
            observed = tracker.update(found)
            find_ms = 1e3 * (time.perf_counter() - t0)
        frame = choose_table_frame(view.T_world_camera, observed, mode=p.table_plane,
                                   max_angle_deg=p.table_plane_max_angle_deg,
                                   max_offset_m=p.table_plane_max_offset_m, find_ms=find_ms)
        self._tables[name] = (key, frame)
        return frame

    @property
    def table_frames(self) -> dict[str, TableFrame]:
        """The latest table frame of each view (diagnostics: ``source``, ``find_ms``...)."""
        return {name: frame for name, (_, frame) in self._tables.items()}

    # ---------------------------------------------------------------------------- stage 1
    def localise(self, views: dict[str, ViewInput]) -> FusionResult:
        """Instance label images of a two-view frame ('top' and 'side'), or of one view alone.

        A view with aligned depth and a table frame (:meth:`table_frame`) is segmented with
        the depth cue (height above the table) fused with the colour cues; otherwise from
        colour alone (the paper). Blobs are also divided where the depth shows the seam of two
        parts (``SegmentationParams.depth_split_jump``; kept apart by the fusion,
        ``FusionParams.keep_depth_splits``), except in the top view: from above, at twice the
        distance and with sparse depth on dark parts, a groove looks like a gap between parts.
        """
        def seg(name: str) -> Segmentation:   # depth splits in every view but the top one
            view = views[name]
            T_world_camera = None if view.depth_m is None else \
                self.table_frame(name, view).T_world_camera
            with_depth = T_world_camera is not None
            pose = view.T_world_camera if T_world_camera is None else T_world_camera
            params = view_segmentation(self.segmentation, self.part_extents_m,
                                       view.intrinsics.K, pose)
            return segment(view.rgb, background=view.background,
                           depth_m=view.depth_m if with_depth else None,
                           intrinsics=view.intrinsics if with_depth else None,
                           T_world_camera=T_world_camera, split_by_depth=name != TOP,
                           params=params)

        if len(views) == 1:   # a rig of one camera: its segmentation, nothing to fuse
            return single_view(seg(*views), *views)
        if missing := set(CAMERA_NAMES) - set(views):
            raise ValueError(f'localise needs top and side or one view; missing {sorted(missing)}')
        if self.localise_params.parallel_views:
            top_future = second_view_thread().submit(seg, TOP)
            side = seg(SIDE)
            top = top_future.result()   # re-raises the top view's error here
        else:
            top, side = seg(TOP), seg(SIDE)
        return fuse_views(top, side, rig=self.rig, side_rgb=views[SIDE].rgb,
                          depth_top_m=views[TOP].depth_m,
                          params=self.fusion.with_parts(self.part_extents_m),
                          top_rgb=views[TOP].rgb)

    # ---------------------------------------------------------------------------- stage 2
    def classify(self, rgb: dict[str, np.ndarray], labels: dict[str, np.ndarray], *,
                 views: dict[str, ViewInput] | None = None) -> dict[int, ClassGuess]:
        """Class of every instance from all the views that see it (one batch per view).

        The linear scores of an instance's crops in the views where it has at least
        ``min_instance_px`` pixels are summed (the two cameras vote), then ranked.

        Args:
            rgb: per view, (H, W, 3) uint8 RGB.
            labels: per view, (H, W) instance label images (0 = background).
            views: per view, the :class:`ViewInput` with the aligned depth, intrinsics and
                ``T_world_camera``; a model trained with shape features ("ours") reads the
                metric shape of each region from them, in the view's table frame
                (:meth:`table_frame`). Without them (or without depth or a table frame in a
                view) such a model falls back to its HOG part.
        """
        if self.classifier is None:
            raise ValueError('no classifier loaded')
        counts, boxes = label_stats(labels)
        min_px = self.classify_params.min_instance_px
        # per view, the instances with enough pixels there
        seen = {view: [int(i) for i in np.flatnonzero(view_counts >= min_px) if i]
                for view, view_counts in counts.items()}
        summed: dict[int, np.ndarray] = {}
        described = []   # per view: (instances, (n, D) descriptors)
        for view in sorted(labels):
            instances = seen[view]
            if not instances or view not in rgb:
                continue
            masks = [mask_in_box(labels[view], i, label_box(boxes[view], i)) for i in instances]
            data = None if views is None else views.get(view)
            # the focal length is the unit of a model's box-size features
            depth: dict[str, np.ndarray | None] = {} if data is None else {'K': data.intrinsics.K}
            if self.classifier.uses_depth and data is not None and data.depth_m is not None:
                depth = {'depth_m': data.depth_m, 'K': data.intrinsics.K,
                         'T_world_camera': self.table_frame(view, data).T_world_camera}
            described.append((instances, self.classifier.describe(
                rgb[view], masks, [label_box(boxes[view], i) for i in instances], **depth)))
        if not described:
            return {}
        # Both views' crops in one call: the model's matrices (~6 MB) are read once a frame.
        scores_all = self.classifier.decision_function(np.vstack([f for _, f in described]))
        row = 0
        for instances, _ in described:
            for instance, scores in zip(instances, scores_all[row:row + len(instances)]):
                summed[instance] = summed.get(instance, 0.0) + scores
            row += len(instances)
        instances = sorted(summed)
        scores = np.stack([summed[i] for i in instances])
        prediction = self.classifier.predict_scores(
            scores, reject_margin=self.classify_params.reject_margin or None)
        cp = self.classify_params
        ranked = self.classifier.ranked_classes(scores, ranking_depth(
            cp.class_candidates, cp.fit_rank_below_margin, cp.fit_rank_max_candidates,
            scores.shape[1]))
        guesses = {}
        for k, instance in enumerate(instances):
            obj_id = int(prediction.class_ids[k])
            margin = float(prediction.margins[k])
            pose_view = preferred_view(counts, instance, min_px=min_px)
            guesses[instance] = ClassGuess(
                obj_id, float(prediction.scores[k]), margin, pose_view,
                self.verification_candidates(obj_id, margin, ranked[k], pose_view))
        return guesses

    def verification_candidates(self, obj_id: int, margin: float, ranked: Sequence[int],
                                view: str | None) -> tuple[int, ...]:
        """The classes the pose stage fits for a part the classifier names ``obj_id`` with
        ``margin``, its pose read in ``view``: its best ``class_candidates`` ranked classes,
        except in the top view when the classifier is sure (``top_view_verify_below_margin``):
        then ``obj_id`` alone; none when unknown. Below ``fit_rank_below_margin``, more of its
        ranked classes, to be ranked by fit (:mod:`tlessbot_ros.core.by_fit`)."""
        if obj_id == UNKNOWN_ID:
            return ()
        scale = self.classifier.margin_scale if self.classifier is not None else 0.0
        cp = self.classify_params
        by_fit = fit_ranked(margin, ranked, scale, below_margin=cp.fit_rank_below_margin,
                            max_candidates=cp.fit_rank_max_candidates)
        if by_fit is not None:
            return by_fit
        ranked = ranked[:cp.class_candidates]
        limit = self.classify_params.top_view_verify_below_margin * scale \
            if view == TOP and scale > 0 else np.inf
        return tuple(int(c) for c in ranked) if margin < limit else (int(obj_id),)

    # ---------------------------------------------------------------------------- stage 3
    def estimate_poses(self, views: dict[str, ViewInput], labels: dict[str, np.ndarray],
                       classes: Mapping[int, int | Sequence[int]], *,
                       box_mode: bool = False,
                       on_detection: Callable[[Detection], None] | None = None,
                       fitter: PartFitter | None = None) -> list[Detection]:
        """Pose of every instance with a known class.

        Args:
            views: per view, the depth, intrinsics and extrinsics (each part is fitted in its
                view's table frame, :meth:`table_frame`: without one, by the fallback).
            labels: label images per view (box mode: boxes, table dropped); trimmed after the fits.
            classes: {instance: obj_id} or {instance: (obj_id, ...)} candidates best first
                (see :class:`ClassGuess`); 0 and ids without templates are skipped, an
                instance without any is skipped. Several candidates are verified by their
                pose fit (``verify_accept_fitness``, ``verify_rmse_weight``).
            box_mode: regions are boxes, not masks (the paper's "GT box" setting): one part each,
                never a fragment of another, whose poses cover it (``FitParams.box_cover``).
            on_detection: called with each detection as soon as it is complete, so a node
                can publish a part's pose without waiting for the rest of the frame (parts
                fitted in parallel complete in any order). A fragment of a larger part
                (``fragment_overlap``) is never handed over, and a part only once those it could
                overlap or touch (theirs too) are fitted: the result does not depend on order.
            fitter: runs the parts' fits (e.g. in worker processes); default: here, in turn.

        Returns: the detections in instance order, fragments left out (regions: trimmed).
        """
        database, detections, jobs = pose_stage(self.pose_estimator).database, [], []
        done = on_detection or (lambda detection: None)
        counts, boxes = label_stats(labels)
        for instance in instance_ids(counts):
            found = np.atleast_1d(classes.get(instance, UNKNOWN_ID))
            candidates = tuple(int(c) for c in found if c != UNKNOWN_ID and c in database)
            view = preferred_view(counts, instance, min_px=self.classify_params.min_instance_px)
            if not candidates or view is None:
                continue
            data = views[view]
            box = label_box(boxes[view], instance)
            mask = mask_in_box(labels[view], instance, box)
            detection = Detection(instance, candidates[0], view, box)
            detections.append(detection)
            if data.depth_m is not None:
                mask = drop_steep(mask, data.depth_m, detection.box, float(data.intrinsics.fx),
                                  self.fit_params.steep_angle_deg)
                points = roi_cloud(data.depth_m, mask, data.intrinsics, box=detection.box)
                frame, fit = self.table_frame(view, data), self.fit_params
                T_world_camera = frame.T_world_camera
                if box_mode and T_world_camera is not None:   # (table_clearance_noise)
                    points = above_table(points, frame, fit.table_clearance_m,
                                         self.table_plane if fit.table_clearance_noise else None)
                detection.n_points = len(points)
                if len(points) >= self.fit_params.min_roi_points:
                    jobs.append(PartJob(detection, points, candidates, T_world_camera,
                                        self._lookalike_views(views, labels, counts, boxes,
                                                              instance, view, candidates),
                                        data.intrinsics.K if box_mode and fit.box_cover else None))
                    continue
                if self.fit_params.unknown_without_fit:   # no depth to fit: unknown
                    mark_unknown(detection, len(candidates))
            done(detection)
        # a ground-truth box is one part, never a fragment (piled keys' boxes overlap)
        last = unknown_last(self.fit_params, jobs, done, self.pose_estimator, box_mode=box_mode)
        last, pieces = split_or_refit(self, views, labels, jobs, last, done, box_mode=box_mode)
        arbiter = one_part_filter(jobs, last, self.fit_params, self.pose_estimator,
                                  0.0 if box_mode else self.fit_params.fragment_overlap,
                                  union_joiner(self, views, labels, jobs),
                                  touch_test(self.fit_params, labels), labels=labels)

        def fitted(job: PartJob) -> None:
            check_fitted_part(self, job, views, labels)   # every view: not in a worker
            check_resting_and_turns(self, job, views, labels)
            arbiter.fitted(job.detection, *fitted_centre(self.pose_estimator, job))

        if fitter is None:
            for job in jobs:
                self.fit_part(job)
                fitted(job)
        else:
            fitter.fit_all(jobs, self.fit_part, fitted)
        kept = join_pieces(arbiter, detections, labels) + pieces   # one_part.py, two_parts.py
        return trim_after_fits(self, views, labels, kept, box_mode=box_mode)   # colour_rim.py

    def _lookalike_views(self, views: dict[str, ViewInput], labels: dict[str, np.ndarray],
                         counts: dict[str, np.ndarray], boxes: dict[str, np.ndarray],
                         instance: int, view: str, candidates: Sequence[int]
                         ) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
        """:attr:`PartJob.more_views` of one part read in ``view``: its ROI clouds in the
        other views where it has at least ``min_instance_px`` pixels, with the rig's
        transforms into them (none without extrinsics or depth, or when no candidate has a
        look-alike or is flat, or with ``lookalike_all_views`` off)."""
        checks = [c for c in (self.lookalike, self.flat_ids) if c is not None]
        if not self.fit_params.lookalike_all_views or views[view].T_world_camera is None or \
                not any(c in check for c in candidates for check in checks):
            return ()
        more = []
        for other in view_order(labels):
            data = views.get(other)
            if other == view or data is None or data.depth_m is None or \
                    data.T_world_camera is None or instance >= len(counts[other]) or \
                    counts[other][instance] < self.classify_params.min_instance_px:
                continue
            box = label_box(boxes[other], instance)
            points = roi_cloud(data.depth_m, mask_in_box(labels[other], instance, box),
                               data.intrinsics, box=box)
            more.append((points, np.linalg.inv(data.T_world_camera) @
                         views[view].T_world_camera))
        return tuple(more)

    def fit_part(self, job: PartJob) -> None:
        """Fit one part's class candidates, keep the best (:func:`~.part_fit.fit_part`)."""
        fit_part(pose_stage(self.pose_estimator), self.fit_params, job)

    def check_lookalike(self, job: PartJob, *,
                        refine: bool | Callable[[], bool] = False) -> None:
        """Compare a fitted part with its look-alike on the depth (part_fit)."""
        check_lookalike(self.lookalike, job, refine=refine)

    # ---------------------------------------------------------------------------- all stages
    def process(self, views: dict[str, ViewInput], *,
                fitter: PartFitter | None = None) -> FrameResult:
        """Localise, classify and estimate poses for one two-view frame, timing each stage
        (``fitter``: see :meth:`estimate_poses`)."""
        t0 = time.perf_counter()
        fusion = self.localise(views)
        t1 = time.perf_counter()
        guesses = self.classify({v: views[v].rgb for v in views}, fusion.labels, views=views)
        t2 = time.perf_counter()
        detections = self.estimate_poses(views, fusion.labels,
                                         {i: g.candidates for i, g in guesses.items()},
                                         fitter=fitter)
        t3 = time.perf_counter()
        for detection in detections:   # a divided region's piece has no guess of its own
            if (guess := guesses.get(detection.instance_id)) is not None:
                detection.class_score, detection.class_margin = guess.score, guess.margin
        return FrameResult(detections, fusion.labels, {
            'segmentation': 1e3 * (t1 - t0), 'classification': 1e3 * (t2 - t1),
            'pose': 1e3 * (t3 - t2), 'frame': 1e3 * (t3 - t0)}, self.table_frames)


__all__ = ['PREFERRED_VIEWS', 'ClassGuess', 'ClassifyParams', 'Detection', 'FitParams',
           'FrameResult', 'LocaliseParams', 'PartFitter', 'PartJob', 'PerceptionPipeline',
           'ViewInput', 'label_counts', 'preferred_view']
