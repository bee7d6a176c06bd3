"""Scoring evaluated frames against BOP ground truth (``tlessbot evaluate``): the report.

Targets are the parts with visib_fract >= 0.3. Poses are matched to ground truth by least
summed pose error within each class, boxes by IoU >= 0.7; the measures are n cm / n° recall,
VSD, ADD-S and the BOP'19 MSSD / MSPD average recalls (:mod:`tlessbot_ros.core.metrics`).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import MeshRenderer, Symmetries, detect_symmetries
from tlessbot_ros.core.metrics import (
    BOP19_MSPD_THRESHOLDS_PX,
    BOP19_THRESHOLDS,
    DUPLICATE_RADIUS_M,
    ModelDepthRenderer,
    adds,
    average_recall,
    box_iou,
    count_duplicates,
    duplicate_radius_m,
    is_correct_cm_deg,
    mspd,
    mssd,
    pose_error,
    vsd,
)
from tlessbot_ros.errors import ModelFileError
from tlessbot_ros.io.bop_results import BopEstimate
from tlessbot_ros.tools.support.eval_breakdown import add_up, confusions, frame_breakdown
from tlessbot_ros.tools.support.unseen_parts import unscored_false_parts_per_frame

MIN_VISIB_FRACT = 0.3
IOU_THRESHOLD = 0.7
VSD_THRESHOLD = 0.3
ADDS_THRESHOLD = 0.1  # × diameter
_MAX_METRIC_POINTS = 1000
_POSE_KEYS = ('recall_5cm5deg', 'recall_1cm5deg', 'recall_vsd03', 'recall_adds01d',
              'mssd_recall', 'mspd_recall')


# ------------------------------------------------------------------------------------------------
# Models


@dataclass
class ScoringModel:
    """What scoring needs of one object (metres)."""

    obj_id: int
    vertices: np.ndarray
    faces: np.ndarray
    diameter_m: float
    symmetries: Symmetries
    points: np.ndarray
    _renderer: ModelDepthRenderer | None = None
    _sym_stack: np.ndarray | None = None

    @property
    def renderer(self) -> ModelDepthRenderer:
        if self._renderer is None:
            self._renderer = ModelDepthRenderer(self.vertices, self.faces)
        return self._renderer

    @property
    def duplicate_radius_m(self) -> float:
        """How close two of its poses lie when they are one part reported twice (m)."""
        return duplicate_radius_m(np.ptp(self.vertices, axis=0))

    @property
    def symmetry_stack(self) -> np.ndarray:
        if self._sym_stack is None:
            self._sym_stack = self.symmetries.transforms(step_rad=np.radians(2.0))
        return self._sym_stack


def scoring_model(obj_id: int, vertices: np.ndarray, faces: np.ndarray, diameter_m: float,
                  symmetries: Symmetries | None = None) -> ScoringModel:
    """A :class:`ScoringModel`; symmetries are detected from the mesh when not given."""
    if symmetries is None:
        symmetries = detect_symmetries(vertices, faces, diameter=diameter_m)
    points = np.asarray(vertices, dtype=np.float64)
    if len(points) > _MAX_METRIC_POINTS:
        points = points[np.random.default_rng(obj_id).choice(len(points), _MAX_METRIC_POINTS,
                                                              replace=False)]
    return ScoringModel(obj_id, np.asarray(vertices, np.float64), np.asarray(faces),
                        float(diameter_m), symmetries, points)


def load_scoring_models(folder: Path, ids: set[int]) -> dict[int, ScoringModel]:
    """Models of ``ids`` from ``folder``; symmetries from models_info.json, else detected."""
    from tlessbot_ros.io.models import load_models
    wanted = sorted(ids)
    models = load_models(folder, wanted)  # ModelFileError names a missing id
    missing = [i for i in wanted if i not in models]
    if missing:
        raise ModelFileError(f'no model for obj_{missing[0]:02d} in {folder}')
    result = {}
    for obj_id in wanted:
        m = models[obj_id]
        result[obj_id] = scoring_model(obj_id, m.vertices, m.faces, m.diameter_m,
                                       m.listed_symmetries())
    return result


# ------------------------------------------------------------------------------------------------
# Scoring


@dataclass
class FrameOutput:
    """What the pipeline (or a results file) produced for one scored image.

    Attributes:
        poses: estimates in the scored camera's frame.
        boxes: (x, y, w, h, obj_id (0 = unknown)) detections in the scored view, or None when
            the localiser did not run (oracle boxes or --poses).
        classified: True when the classes of ``boxes`` came from the classifier.
        classes_by_gt: {GT index: class} when the classifier ran on ground-truth boxes
            (``--oracle boxes``), after the pose stage's verification where it ran; else None.
        classifier_by_gt: {GT index: (class, margin)} of the classifier alone (before the pose
            stage) with ``--oracle boxes``, else None.
        background_named: with ``evaluate --background-boxes``, the class each background
            box was given (0 = unknown; anything else is a false positive); else None.
        pose_ran: False where the pose stage was skipped (a frame without depth).
        labels: (H, W) instance labels of the scored view behind ``boxes`` (one box per
            label, in label order), or None: then no breakdown of the detection losses.
        timings_ms: per-stage wall times of this frame (ms); ``pose_per_part``: the pose
            stage over the parts it fitted, ``table_plane``: finding the table plane in the
            views' depth (all views).
    """

    poses: list[BopEstimate] = field(default_factory=list)
    boxes: list[tuple[int, int, int, int, int]] | None = None
    classified: bool = False
    classes_by_gt: dict[int, int] | None = None
    classifier_by_gt: dict[int, tuple[int, float]] | None = None
    background_named: list[int] | None = None
    pose_ran: bool = True
    timings_ms: dict[str, float] = field(default_factory=dict)
    labels: np.ndarray | None = None


@dataclass
class _Target:
    obj_id: int
    pose_5cm5deg: bool = False
    pose_1cm5deg: bool = False
    vsd_ok: bool = False
    adds_ok: bool = False
    mssd_error: float = np.inf
    mspd_error: float = np.inf
    mspd_scale: float = 1.0
    detected: bool | None = None
    recognised: bool | None = None
    unknown: bool = False
    posed: bool = True


def match_poses(image, poses: list[BopEstimate],
                 models: dict[int, ScoringModel]) -> dict[int, BopEstimate]:
    """{gt index: estimate}: per class, the assignment of estimates to parts whose summed
    symmetry-aware error (degrees + millimetres) is least. Nearest centres alone hand a right
    pose another part's truth when parts of one class lie close together (a pile of keys)."""
    from scipy.optimize import linear_sum_assignment

    taken: dict[int, BopEstimate] = {}
    for obj_id in {est.obj_id for est in poses}:
        truth = [k for k, gt in enumerate(image.gt) if gt.obj_id == obj_id]
        ours = [est for est in poses if est.obj_id == obj_id]
        if not truth:
            continue
        symmetries = models[obj_id].symmetries if obj_id in models else None
        cost = np.empty((len(ours), len(truth)))
        for i, est in enumerate(ours):
            for j, k in enumerate(truth):
                cost[i, j] = pose_error(est.T_camera_object, image.gt[k].T_camera_object,
                                        symmetries).ranking
        for i, j in zip(*linear_sum_assignment(cost)):
            taken[truth[j]] = ours[i]
    return taken


def _match_boxes(image, boxes) -> tuple[dict[int, int], int]:
    """Greedy by IoU >= 0.7: {gt index: box index}, and the count of unmatched boxes."""
    pairs = []
    for k, gt in enumerate(image.gt):
        if gt.bbox_visib is None or gt.bbox_visib[2] <= 0:
            continue
        for j, box in enumerate(boxes):
            iou = box_iou(gt.bbox_visib, box[:4])
            if iou >= IOU_THRESHOLD:
                pairs.append((iou, k, j))
    matched: dict[int, int] = {}
    used: set[int] = set()
    for _, k, j in sorted(pairs, reverse=True):
        if k not in matched and j not in used:
            matched[k] = j
            used.add(j)
    return matched, len(boxes) - len(used)


def with_visible_masks(image, models: dict[int, ScoringModel]):
    """``image`` (a BopImage) with each part's visible mask ray-cast from its ground-truth pose
    where the dataset has none (a BOP set without ``mask_visib/``): parts hide each other by
    depth, nothing else hides them. Unchanged when every part has its mask."""
    if all(gt.mask is not None for gt in image.gt) or \
            any(gt.obj_id not in models for gt in image.gt):
        return image
    renderer = MeshRenderer()
    for gt in image.gt:
        renderer.add_mesh(models[gt.obj_id].vertices, models[gt.obj_id].faces,
                          gt.T_camera_object)
    instance = renderer.render(image.intrinsics, np.eye(4)).instance
    return replace(image, gt=[gt if gt.mask is not None else replace(gt, mask=instance == k)
                              for k, gt in enumerate(image.gt)])


def _regions(output: FrameOutput, box_matches: dict[int, int]) -> tuple[int, int] | None:
    """(regions named as a part that are none, regions reported unknown) of one frame: the
    localiser's regions, or the ground-truth and ``background_named`` boxes; None when the
    frame shows no region that is no part (ground-truth boxes alone, or given poses)."""
    if output.boxes is not None:
        matched = set(box_matches.values())
        return (sum(j not in matched and box[4] != 0 for j, box in enumerate(output.boxes)),
                sum(box[4] == 0 for box in output.boxes))
    if output.background_named is None:
        return None
    named = output.background_named
    unknown_parts = sum(c == 0 for c in (output.classes_by_gt or {}).values())
    return sum(c != 0 for c in named), sum(c == 0 for c in named) + unknown_parts


def _score_pose(target: _Target, T_est: np.ndarray, T_gt: np.ndarray, model: ScoringModel,
                image) -> None:
    """Fill ``target``'s pose measures of an estimate against the truth."""
    error = pose_error(T_est, T_gt, model.symmetries)
    target.pose_5cm5deg = is_correct_cm_deg(error)
    target.pose_1cm5deg = is_correct_cm_deg(error, translation_m=0.01)
    target.adds_ok = adds(T_est, T_gt, model.vertices) < ADDS_THRESHOLD * model.diameter_m
    target.mssd_error = mssd(T_est, T_gt, model.points, model.symmetry_stack)
    target.mspd_error = mspd(T_est, T_gt, model.points, image.intrinsics.K,
                             model.symmetry_stack)
    if image.depth_m is not None:
        target.vsd_ok = bool(vsd(T_est, T_gt, image.depth_m, image.intrinsics,
                                 model.renderer)[0] < VSD_THRESHOLD)


def _measures(everything: list[_Target], models: dict[int, ScoringModel], *, has_depth: bool,
              detection_ran: bool, recognition_ran: bool) -> dict:
    """The recalls, detection and recognition rates of a group of targets; the pose recalls
    over the targets of frames where the pose stage ran (None if none)."""
    if not everything:
        return {'objects_gt': 0}
    group = [t for t in everything if t.posed]
    out: dict = {key: None for key in _POSE_KEYS}
    if group:
        n = len(group)
        diam = np.array([models[t.obj_id].diameter_m for t in group])
        mssd_rel = np.array([t.mssd_error for t in group]) / diam
        mspd_px = np.array([t.mspd_error * t.mspd_scale for t in group])
        out.update({
            'recall_5cm5deg': sum(t.pose_5cm5deg for t in group) / n,
            'recall_1cm5deg': sum(t.pose_1cm5deg for t in group) / n,
            'recall_vsd03': sum(t.vsd_ok for t in group) / n if has_depth else None,
            'recall_adds01d': sum(t.adds_ok for t in group) / n,
            'mssd_recall': average_recall(mssd_rel, BOP19_THRESHOLDS),
            'mspd_recall': average_recall(mspd_px, BOP19_MSPD_THRESHOLDS_PX)})
    out.update({
        'objects_gt': len(everything),
        'objects_posed': len(group),
        'iou07_rate': (sum(bool(t.detected) for t in everything) / len(everything))
        if detection_ran else None})
    detected = [t for t in everything if t.detected or t.recognised is not None]
    out['top1'] = (sum(bool(t.recognised) for t in detected) / len(detected)
                   if recognition_ran and detected else None)
    return out


def _unknowns(targets: list[_Target], regions: list[tuple[int, int]], ran: bool) -> dict:
    """The parts called unknown (share of the recognised targets), and per frame of those
    that show regions that are no part: such regions named as a part (false positives) and
    all regions called unknown."""
    named = [t for t in targets if t.recognised is not None]
    return {'unknown_rate': sum(t.unknown for t in named) / len(named) if ran and named
            else None,
            'false_pos_per_frame': sum(r[0] for r in regions) / len(regions) if regions
            else None,
            'unknown_per_frame': sum(r[1] for r in regions) / len(regions) if regions
            else None}


def repeated_poses(poses: list[BopEstimate], models: dict[int, ScoringModel]) -> int:
    """How many of one frame's poses repeat another (:func:`count_duplicates`), each with the
    radius of its part (:func:`duplicate_radius_m`; the fixed one for a part not scored)."""
    return count_duplicates(
        np.array([p.T_camera_object[:3, 3] for p in poses]).reshape(-1, 3),
        radius_m=np.array([models[p.obj_id].duplicate_radius_m if p.obj_id in models
                           else DUPLICATE_RADIUS_M for p in poses]))


def score_frames(frames: list[tuple[object, FrameOutput]],
                 models: dict[int, ScoringModel]) -> dict:
    """The report dictionary (see issue 8) from (BopImage, FrameOutput) pairs; with the false
    parts outside the scored camera (:mod:`.unseen_parts`), a figure apart from the false
    positives, so that earlier reports stay comparable."""
    report = _scored_frames(frames, models)
    report['detection']['unscored_false_parts_per_frame'] = unscored_false_parts_per_frame(
        frames, lambda i: models[i].diameter_m / 2 if i in models else DUPLICATE_RADIUS_M)
    return report


def _scored_frames(frames: list[tuple[object, FrameOutput]],
                   models: dict[int, ScoringModel]) -> dict:
    """The report dictionary but the false parts outside the scored camera."""
    targets: list[_Target] = []
    false_pos = duplicates = 0
    regions: list[tuple[int, int]] = []   # per frame: (named but no part, called unknown)
    losses, matched_boxes = [], []
    detection_ran = recognition_ran = False
    for image, output in frames:
        matches = match_poses(image, output.poses, models)
        duplicates += repeated_poses(output.poses, models)
        box_matches: dict[int, int] = {}
        if output.boxes is not None:
            detection_ran = True
            box_matches, unmatched = _match_boxes(image, output.boxes)
            false_pos += unmatched
            matched_boxes.append((image, output.boxes, box_matches))
            if output.labels is not None:
                losses.append(frame_breakdown(with_visible_masks(image, models),
                                              output.labels, output.boxes, box_matches))
        if (counts := _regions(output, box_matches)) is not None:
            regions.append(counts)
        recognition_ran |= output.classified or output.classes_by_gt is not None
        for k, gt in enumerate(image.gt):
            if gt.visib_fract is None or gt.visib_fract < MIN_VISIB_FRACT:
                continue
            if gt.obj_id not in models:
                raise ModelFileError(f'no model for obj_{gt.obj_id:02d}')
            model = models[gt.obj_id]
            target = _Target(gt.obj_id, mspd_scale=640.0 / image.intrinsics.width,
                             posed=output.pose_ran)
            if output.boxes is not None:
                target.detected = k in box_matches
                if output.classified and target.detected:
                    target.recognised = output.boxes[box_matches[k]][4] == gt.obj_id
                    target.unknown = output.boxes[box_matches[k]][4] == 0
            elif output.classes_by_gt is not None:
                target.detected = True  # the box is given
                target.recognised = output.classes_by_gt.get(k) == gt.obj_id
                target.unknown = output.classes_by_gt.get(k) == 0
            est = matches.get(k)
            if est is not None:
                _score_pose(target, est.T_camera_object, gt.T_camera_object, model, image)
            targets.append(target)
    has_depth = all(image.depth_m is not None for image, o in frames if o.pose_ran)

    def measures(group: list[_Target]) -> dict:
        return _measures(group, models, has_depth=has_depth, detection_ran=detection_ran,
                         recognition_ran=recognition_ran)

    overall = measures(targets)
    per_object = {}
    for obj_id in sorted({t.obj_id for t in targets}):
        per_object[str(obj_id)] = measures([t for t in targets if t.obj_id == obj_id])

    def median(stage: str) -> float | None:
        values = [o.timings_ms[stage] for _, o in frames if stage in o.timings_ms]
        return float(np.median(values)) if values else None

    return {
        'frames': len(frames),
        'objects_gt': len(targets),
        'detection': {
            'iou07_rate': overall.get('iou07_rate'),
            'false_pos_per_frame': (false_pos / len(frames)
                                    if detection_ran and frames else None),
            'duplicates_per_frame': duplicates / len(frames) if frames else None,
            'breakdown': {**add_up(losses), 'confusions': confusions(matched_boxes)}
            if losses else None},
        'recognition': {'top1': overall.get('top1'), **_unknowns(targets, regions,
                                                                  recognition_ran)},
        'pose': {key: overall.get(key) for key in _POSE_KEYS},
        'skipped': {'pose_frames_without_depth': sum(not o.pose_ran for _, o in frames),
                    'parts_not_posed': len(targets) - overall.get('objects_posed', 0)},
        'timing_ms': {stage: median(stage) for stage in (
            'segmentation', 'classification', 'pose', 'frame', 'pose_per_part',
            'table_plane')},
        'per_object': per_object,
    }
