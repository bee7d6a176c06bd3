"""Score the pipeline (or given poses) on a BOP-format dataset: report.json, report.md, plots.

  tlessbot evaluate --dataset DIR --models DIR [--split NAME] [--classifier FILE]
                    [--templates FILE] [--oracle none|boxes|boxes+classes]
                    [--poses RESULTS.csv] [--limit N] [--out DIR]

With --poses the given BOP results are only scored. Otherwise the perception pipeline
(core.pipeline) runs on every frame; --oracle feeds ground-truth boxes (and classes) instead of
the localiser (and classifier). A dataset with test_top/ and test_side/ is evaluated as two views
and scored in the side camera. Parts with visib_fract >= 0.3 are the targets.
"""
from __future__ import annotations

import argparse
import json
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from tlessbot_ros.core.common import Symmetries, detect_symmetries
from tlessbot_ros.core.metrics import (
    BOP19_MSPD_THRESHOLDS_PX,
    BOP19_THRESHOLDS,
    ModelDepthRenderer,
    adds,
    average_recall,
    box_iou,
    is_correct_cm_deg,
    mspd,
    mssd,
    pose_error,
    vsd,
)
from tlessbot_ros.errors import DatasetError, ModelFileError, TlessbotError
from tlessbot_ros.io.bop_results import PoseResult, read_results, write_results

MIN_VISIB_FRACT = 0.3
IOU_THRESHOLD = 0.7
VSD_THRESHOLD = 0.3
ADDS_THRESHOLD = 0.1  # × diameter
TWO_VIEW_SPLITS = ('test_top', 'test_side')
_MAX_METRIC_POINTS = 1000


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--dataset', type=Path, help='BOP dataset root')
    parser.add_argument('--bag', type=Path,
                        help='instead of --dataset: a bag with /ground_truth topics, replayed '
                             'through the ROS graph (each node its own process)')
    parser.add_argument('--models', required=True, type=Path,
                        help='CAD models: obj_NN.stl folder or BOP models/ with models_info.json')
    parser.add_argument('--split', help='evaluate this single split (default: test_top + '
                        'test_side when both exist, else the only split)')
    parser.add_argument('--classifier', type=Path, help='classifier .npz (tlessbot train)')
    parser.add_argument('--templates', type=Path, help='template database .npz '
                        '(tlessbot templates)')
    parser.add_argument('--oracle', choices=('none', 'boxes', 'boxes+classes'), default='none',
                        help='feed ground-truth boxes (and classes) to the pipeline')
    parser.add_argument('--poses', type=Path, help='only score these poses (BOP results CSV)')
    parser.add_argument('--limit', type=int, help='score at most N frames')
    parser.add_argument('--out', type=Path, default=Path('eval_out'), help='output folder')
    parser.add_argument('--pose-workers', type=int, default=0, metavar='N',
                        help='fit parts in N worker processes besides this one, as the pose '
                             'node does (config/cell.yaml: 1); the poses are the same')
    parser.add_argument('--pose-param', action='append', metavar='NAME=VALUE',
                        help='override a PoseParams field, e.g. icp_iterations=6 (repeatable)')
    parser.add_argument('--pipeline-param', action='append', metavar='NAME=VALUE',
                        help='override a LocaliseParams, ClassifyParams or FitParams field, e.g. '
                             'verify_accept_fitness=0.9 '
                             '(repeatable)')



def _stage_params(assignments: list[str] | None) -> dict[str, Any]:
    """``--pipeline-param NAME=VALUE`` applied to the stage dataclass with field NAME, as
    PerceptionPipeline keyword arguments."""
    import dataclasses

    from tlessbot_ros.core.pipeline import ClassifyParams, FitParams, LocaliseParams
    from tlessbot_ros.tools._overrides import apply_overrides

    stages = {'localise_params': LocaliseParams(), 'classify_params': ClassifyParams(),
              'fit_params': FitParams()}
    owner = {f.name: key for key, params in stages.items() for f in dataclasses.fields(params)}
    for assignment in assignments or []:
        key = owner.get(assignment.partition('=')[0])
        if key is None:
            raise TlessbotError(f'expected NAME=VALUE with NAME one of '
                                f'{", ".join(sorted(owner))}; got {assignment!r}')
        try:
            stages[key] = apply_overrides(stages[key], [assignment])
        except ValueError as error:   # the dataclass's validation: says how to fix it
            raise TlessbotError(f'--pipeline-param {error}') from None
    return stages

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
            (``--oracle boxes``), else None.
        timings_ms: per-stage wall times of this frame.
    """

    poses: list[PoseResult] = field(default_factory=list)
    boxes: list[tuple[int, int, int, int, int]] | None = None
    classified: bool = False
    classes_by_gt: dict[int, int] | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)


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


def _match_poses(image, poses: list[PoseResult]) -> dict[int, PoseResult]:
    """Greedy by score: each estimate takes the nearest unmatched GT of its class."""
    taken: dict[int, PoseResult] = {}
    for est in sorted(poses, key=lambda p: -p.score):
        best, best_d = None, np.inf
        for k, gt in enumerate(image.gt):
            if k in taken or gt.obj_id != est.obj_id:
                continue
            d = float(np.linalg.norm(gt.T_camera_object[:3, 3] - est.T_camera_object[:3, 3]))
            if d < best_d:
                best, best_d = k, d
        if best is not None:
            taken[best] = est
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


def score_frames(frames: list[tuple[object, FrameOutput]],
                 models: dict[int, ScoringModel]) -> dict:
    """The report dictionary (see issue 8) from (BopImage, FrameOutput) pairs."""
    targets: list[_Target] = []
    false_pos = 0
    detection_ran = recognition_ran = False
    for image, output in frames:
        matches = _match_poses(image, output.poses)
        box_matches: dict[int, int] = {}
        if output.boxes is not None:
            detection_ran = True
            box_matches, unmatched = _match_boxes(image, output.boxes)
            false_pos += unmatched
        recognition_ran |= output.classified or output.classes_by_gt is not None
        for k, gt in enumerate(image.gt):
            if gt.visib_fract is None or gt.visib_fract < MIN_VISIB_FRACT:
                continue
            if gt.obj_id not in models:
                raise ModelFileError(f'no model for obj_{gt.obj_id:02d}')
            model = models[gt.obj_id]
            target = _Target(gt.obj_id, mspd_scale=640.0 / image.intrinsics.width)
            if output.boxes is not None:
                target.detected = k in box_matches
                if output.classified and target.detected:
                    target.recognised = output.boxes[box_matches[k]][4] == gt.obj_id
            elif output.classes_by_gt is not None:
                target.detected = True  # the box is given
                target.recognised = output.classes_by_gt.get(k) == gt.obj_id
            est = matches.get(k)
            if est is not None:
                T_est, T_gt = est.T_camera_object, gt.T_camera_object
                error = pose_error(T_est, T_gt, model.symmetries)
                target.pose_5cm5deg = is_correct_cm_deg(error)
                target.pose_1cm5deg = is_correct_cm_deg(error, translation_m=0.01)
                target.adds_ok = adds(T_est, T_gt, model.points) \
                    < ADDS_THRESHOLD * model.diameter_m
                target.mssd_error = mssd(T_est, T_gt, model.points, model.symmetry_stack)
                target.mspd_error = mspd(T_est, T_gt, model.points, image.intrinsics.K,
                                         model.symmetry_stack)
                if image.depth_m is not None:
                    target.vsd_ok = bool(vsd(T_est, T_gt, image.depth_m, image.intrinsics,
                                             model.renderer)[0] < VSD_THRESHOLD)
            targets.append(target)
    has_depth = all(image.depth_m is not None for image, _ in frames)

    def measures(group: list[_Target]) -> dict:
        n = len(group)
        if n == 0:
            return {'objects_gt': 0}
        diam = np.array([models[t.obj_id].diameter_m for t in group])
        mssd_rel = np.array([t.mssd_error for t in group]) / diam
        mspd_px = np.array([t.mspd_error * t.mspd_scale for t in group])
        out = {
            'objects_gt': n,
            'recall_5cm5deg': sum(t.pose_5cm5deg for t in group) / n,
            'recall_1cm5deg': sum(t.pose_1cm5deg for t in group) / n,
            'recall_vsd03': sum(t.vsd_ok for t in group) / n if has_depth else None,
            'recall_adds01d': sum(t.adds_ok for t in group) / n,
            'mssd_recall': average_recall(mssd_rel, BOP19_THRESHOLDS),
            'mspd_recall': average_recall(mspd_px, BOP19_MSPD_THRESHOLDS_PX),
            'iou07_rate': (sum(bool(t.detected) for t in group) / n) if detection_ran else None,
        }
        detected = [t for t in group if t.detected or t.recognised is not None]
        out['top1'] = (sum(bool(t.recognised) for t in detected) / len(detected)
                       if recognition_ran and detected else None)
        return out

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
                                    if detection_ran and frames else None)},
        'recognition': {'top1': overall.get('top1')},
        'pose': {key: overall.get(key) for key in (
            'recall_5cm5deg', 'recall_1cm5deg', 'recall_vsd03', 'recall_adds01d',
            'mssd_recall', 'mspd_recall')},
        'timing_ms': {stage: median(stage) for stage in (
            'segmentation', 'classification', 'pose', 'frame')},
        'per_object': per_object,
    }


# ------------------------------------------------------------------------------------------------
# Data sources


def _scored_split(dataset: Path, split: str | None) -> tuple[str, bool]:
    """(split to score, two-view?) after checking the dataset layout."""
    from tlessbot_ros.io.bop import list_splits
    splits = list_splits(dataset)
    if split is not None:
        if split not in splits:
            raise DatasetError(f'{dataset} has no split {split!r} (available: '
                               f'{", ".join(splits)})')
        return split, False
    if all(s in splits for s in TWO_VIEW_SPLITS):
        return 'test_side', True
    if len(splits) == 1:
        return splits[0], False
    raise DatasetError(f'{dataset} has several splits ({", ".join(splits)}); choose one with '
                       '--split')


def _given_poses(path: Path) -> dict[tuple[int, int], FrameOutput]:
    outputs: dict[tuple[int, int], FrameOutput] = {}
    for result in read_results(path):
        output = outputs.setdefault((result.scene_id, result.im_id), FrameOutput())
        output.poses.append(result)
        if result.time_s >= 0:
            output.timings_ms['frame'] = 1e3 * result.time_s
    return outputs


def _pipeline_frames(args: argparse.Namespace, split: str, two_view: bool,
                     ) -> Iterator[tuple[object, FrameOutput]]:
    """Run core.pipeline on every frame (or the oracle variants)."""
    if args.templates is None:
        args.templates = _cached_model(args, 'templates')
    if args.oracle != 'boxes+classes' and args.classifier is None:
        args.classifier = _cached_model(args, 'train')
    if args.oracle == 'none' and not two_view:
        raise TlessbotError('--oracle none needs a two-view dataset (test_top + test_side); '
                            'use --oracle boxes or boxes+classes for a single split')
    from tlessbot_ros.core.common import CameraMount, Rig, mask_box
    from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
    from tlessbot_ros.core.pose import PoseParams, TemplateDatabase
    from tlessbot_ros.core.recognise import LinearClassifier
    from tlessbot_ros.io.bop import read_split
    from tlessbot_ros.tools._overrides import apply_overrides

    templates = TemplateDatabase.load(args.templates)
    classifier = LinearClassifier.load(args.classifier) if args.classifier else None
    views = ('top', 'side') if two_view else ('side',)
    splits = {'top': 'test_top', 'side': 'test_side'} if two_view else {'side': split}
    readers = {v: read_split(args.dataset, splits[v], limit=args.limit) for v in views}
    # Empty-table images (``tlessbot simulate --backgrounds``) feed background subtraction.
    backgrounds = {v: read_split(args.dataset, f'background_{v}', limit=args.limit,
                                 load_masks=False)
                   for v in views if (args.dataset / f'background_{v}').is_dir()}
    pose_params = apply_overrides(PoseParams(), args.pose_param)
    stage_params = _stage_params(args.pipeline_param)
    if args.oracle == 'boxes+classes':
        # the classes are the truth: nothing for the look-alike check to correct
        stage_params['fit_params'] = replace(stage_params['fit_params'], lookalike_check=False)
    workers = None
    if args.pose_workers > 0:
        from tlessbot_ros.parallel.pose_pool import PoseWorkerParams, PoseWorkerPool
        workers = PoseWorkerPool(args.templates, pose=pose_params, fit=stage_params['fit_params'],
                                 params=PoseWorkerParams(count=args.pose_workers))
        if not workers.wait_ready():
            workers.close()
            raise TlessbotError(f'pose workers did not start: {"; ".join(workers.errors)}')
    try:
        pipeline = None
        for images in zip(*readers.values()):
            by_view = dict(zip(views, images))
            empty = {v: next(reader).rgb for v, reader in backgrounds.items()}
            scored = by_view['side']
            keys = {(im.scene_id, im.im_id) for im in images}
            if len(keys) != 1:
                raise DatasetError('test_top and test_side do not hold the same scene/image ids')
            inputs = {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera,
                                   background=empty.get(v))
                      for v, im in by_view.items()}
            if pipeline is None:
                rig = None
                if all(im.T_world_camera is not None for im in images):
                    rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                               for v, im in by_view.items()})
                pipeline = PerceptionPipeline(rig=rig, classifier=classifier, templates=templates,
                                              pose=pose_params, **stage_params)
            output = FrameOutput()
            t0 = time.perf_counter()
            if args.oracle == 'none':
                result = pipeline.process(inputs, fitter=workers)
                detections, labels = result.detections, result.labels
                output.timings_ms.update(result.timings_ms)
                output.classified = True
                output.boxes = []
                side_labels = labels.get('side')
                by_instance = {d.instance_id: d.obj_id for d in detections}
                if side_labels is not None:
                    for instance in np.unique(side_labels):
                        if instance == 0:
                            continue
                        box = mask_box(side_labels == instance)
                        output.boxes.append((*box, int(by_instance.get(int(instance), 0))))
            else:
                labels = _oracle_labels(by_view)
                if args.oracle == 'boxes+classes':
                    classes = {k + 1: gt.obj_id for k, gt in enumerate(scored.gt)}
                else:
                    t1 = time.perf_counter()
                    guesses = pipeline.classify({v: im.rgb for v, im in by_view.items()}, labels,
                                                views=inputs)
                    output.timings_ms['classification'] = 1e3 * (time.perf_counter() - t1)
                    classes = {i: g.candidates for i, g in guesses.items()}
                t2 = time.perf_counter()
                detections = pipeline.estimate_poses(inputs, labels, classes, box_mode=True,
                                                     fitter=workers)
                if args.oracle == 'boxes':  # the class after verification by the pose fit
                    output.classes_by_gt = {i - 1: g.obj_id for i, g in guesses.items()}
                    output.classes_by_gt.update({d.instance_id - 1: d.obj_id for d in detections})
                output.timings_ms['pose'] = 1e3 * (time.perf_counter() - t2)
                output.timings_ms['frame'] = 1e3 * (time.perf_counter() - t0)
            frame_s = output.timings_ms.get('frame', 1e3 * (time.perf_counter() - t0)) / 1e3
            for d in detections:
                if d.pose is None:
                    continue
                T = d.pose.T_camera_object
                if d.view != 'side':
                    src = by_view[d.view]
                    T = np.linalg.inv(scored.T_world_camera) @ src.T_world_camera @ T
                output.poses.append(PoseResult(scored.scene_id, scored.im_id, d.obj_id,
                                               float(d.pose.fitness), T, frame_s))
            yield scored, output
    finally:
        if workers is not None:
            workers.close()


def _cached_model(args: argparse.Namespace, command: str) -> Path:
    """``<out>/templates.npz`` or ``<out>/classifier.npz`` built from ``--models`` with the
    default settings (``tlessbot templates`` / ``tlessbot train``, progress bar shown) unless
    an earlier run cached it."""
    import subprocess
    import sys

    name = 'templates.npz' if command == 'templates' else 'classifier.npz'
    path = args.out / name
    if path.is_file():
        print(f'using cached {path}')
        return path
    args.out.mkdir(parents=True, exist_ok=True)
    print(f'no --{"templates" if command == "templates" else "classifier"} given: building '
          f'{path} from {args.models} with the default settings')
    result = subprocess.run([sys.executable, '-m', 'tlessbot_ros.tools.cli', command,
                             '--models', str(args.models), '--out', str(path)])
    if result.returncode != 0 or not path.is_file():
        raise TlessbotError(f'building {path} failed (tlessbot {command} exited with '
                            f'{result.returncode})')
    return path


def _oracle_labels(by_view: dict) -> dict[str, np.ndarray]:
    """Instance label images from the GT visible boxes (instance k + 1 = GT k), small on top."""
    labels = {}
    for view, image in by_view.items():
        label = np.zeros((image.intrinsics.height, image.intrinsics.width), np.uint16)
        boxes = [(k, gt.bbox_visib) for k, gt in enumerate(image.gt)
                 if gt.bbox_visib is not None and gt.bbox_visib[2] > 0
                 and (gt.visib_fract or 0) > 0]
        for k, (x, y, w, h) in sorted(boxes, key=lambda b: -b[1][2] * b[1][3]):
            label[y:y + h, x:x + w] = k + 1
        labels[view] = label
    return labels


# ------------------------------------------------------------------------------------------------


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from tlessbot_ros.io.bop import read_split
    from tlessbot_ros.tools._report import write_report

    if args.limit is not None and args.limit <= 0:
        raise TlessbotError('--limit must be positive')
    if not args.models.is_dir():
        raise ModelFileError(f'models folder not found: {args.models}')
    if (args.dataset is None) == (args.bag is None):
        raise TlessbotError('give exactly one of --dataset DIR and --bag FILE')
    started = time.perf_counter()
    frames: list[tuple[object, FrameOutput]] = []
    if args.bag is not None:
        frames, split, two_view = _bag_frames(args), 'bag (side camera)', True
        mode = f'ROS graph on {args.bag.name}'
    elif args.poses is not None:
        split, two_view = _scored_split(args.dataset, args.split)
        given = _given_poses(args.poses)
        images = read_split(args.dataset, split, limit=args.limit, load_masks=False)
        for image in tqdm(images, desc='scoring', unit='frame', total=args.limit):
            frames.append((image, given.get((image.scene_id, image.im_id), FrameOutput())))
        mode = f'given poses ({args.poses.name})'
    else:
        split, two_view = _scored_split(args.dataset, args.split)
        iterator = _pipeline_frames(args, split, two_view)
        for item in tqdm(iterator, desc='pipeline', unit='frame', total=args.limit):
            frames.append(item)
        mode = f'pipeline, oracle {args.oracle}'
    if not frames:
        raise DatasetError(f'{args.dataset or args.bag}: {split} has no images')
    ids = {gt.obj_id for image, _ in frames for gt in image.gt}
    ids |= {p.obj_id for _, o in frames for p in o.poses}
    models = load_scoring_models(args.models, ids)
    report = score_frames(frames, models)
    report['mode'] = mode
    report['dataset'] = str(args.dataset or args.bag)
    report['split'] = 'test_top + test_side' if two_view else split
    report['run_time_s'] = time.perf_counter() - started
    args.out.mkdir(parents=True, exist_ok=True)
    write_results(args.out / 'estimates.csv', [p for _, o in frames for p in o.poses])
    (args.out / 'report.json').write_text(json.dumps(report, indent=2) + '\n')
    write_report(report, args.out)
    pose = report['pose']
    print(f'{report["frames"]} frames, {report["objects_gt"]} parts: '
          f'5cm5deg {_fmt(pose["recall_5cm5deg"])}, VSD<0.3 {_fmt(pose["recall_vsd03"])}, '
          f'ADD-S {_fmt(pose["recall_adds01d"])}, MSSD AR {_fmt(pose["mssd_recall"])} '
          f'-> {args.out}')
    return 0


def _bag_frames(args: argparse.Namespace) -> list[tuple[object, FrameOutput]]:
    """Replay a simulated bag through the graph (lock-step) and pair its poses with the bag's
    ground truth, all in the side camera (top-view poses through the rig extrinsics)."""
    from types import SimpleNamespace

    from tlessbot_ros.conversions import camera_info_to_intrinsics, depth_image_to_metres
    from tlessbot_ros.core.common import rig_from_params
    from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_TEMPLATES
    from tlessbot_ros.io.bags import deserialize, read_bag
    from tlessbot_ros.io.config import default_config_path, load_ros_params
    from tlessbot_ros.io.ground_truth import read_ground_truth
    from tlessbot_ros.tools._graph_run import run_graph_on_bag

    config = default_config_path()
    rig = rig_from_params(load_ros_params(config))
    T_side_top = rig.T_a_b('side', 'top')
    truth = read_ground_truth(args.bag)
    depth, intrinsics = {}, {}
    for message in read_bag(args.bag, ['/side/aligned_depth_to_color/image_raw',
                                       '/side/aligned_depth_to_color/camera_info']):
        msg = deserialize(message)
        if message.msgtype == 'sensor_msgs/msg/Image':
            depth[message.log_time_ns] = depth_image_to_metres(msg)
        else:
            intrinsics[message.log_time_ns] = camera_info_to_intrinsics(msg)
    classifier = args.classifier or DEFAULT_CLASSIFIER
    templates = args.templates or DEFAULT_TEMPLATES
    for path in (classifier, templates):
        if not Path(path).is_file():
            raise ModelFileError(f'model file not found: {path}')
    run = run_graph_on_bag(args.bag, config=config, lockstep=True, ros_args=[
        '-p', f'model_path:={classifier}', '-p', f'templates_path:={templates}'])
    poses: dict[int, list[PoseResult]] = {}
    for pose in run.poses:
        T = pose.T if pose.frame_id.startswith('side') else T_side_top @ pose.T
        poses.setdefault(pose.stamp_ns, []).append(PoseResult(0, 0, pose.obj_id, 1.0, T))
    frames = []
    for index, stamp in enumerate(sorted(truth)[:args.limit]):
        gt = [SimpleNamespace(obj_id=p.obj_id, visib_fract=p.visib_fract.get('side', 0.0),
                              bbox_visib=p.bbox_visib.get('side'),
                              T_camera_object=p.T_camera_object['side_color_optical_frame'])
              for p in truth[stamp] if 'side_color_optical_frame' in p.T_camera_object]
        image = SimpleNamespace(scene_id=0, im_id=index, gt=gt, depth_m=depth.get(stamp),
                                intrinsics=intrinsics.get(stamp))
        for estimate in poses.get(stamp, []):
            estimate.im_id = index
        frames.append((image, FrameOutput(poses=poses.get(stamp, []))))
    return frames


def _fmt(value: float | None) -> str:
    return 'n/a' if value is None else f'{value:.3f}'
