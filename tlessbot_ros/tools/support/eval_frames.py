"""Where ``tlessbot evaluate`` gets its frames: the pipeline on a BOP dataset (or its oracle
variants) and the ROS graph on a bag. Each yields (image, FrameOutput) pairs for
:func:`~tlessbot_ros.tools.support.eval_scoring.score_frames`, poses in the side camera.
"""
from __future__ import annotations

import time
from collections.abc import Collection, Iterator
from dataclasses import replace
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import CAMERA_NAMES, SIDE, TOP
from tlessbot_ros.errors import DatasetError, ModelFileError, TlessbotError
from tlessbot_ros.io.bop_results import BopEstimate
from tlessbot_ros.tools.support.eval_scoring import FrameOutput

TWO_VIEW_SPLITS = tuple(f'test_{camera}' for camera in CAMERA_NAMES)


def pipeline_frames(dataset: Path, split: str, two_view: bool, *, templates: Path,
                    classifier: Path | None, oracle: str = 'none', limit: int | None = None,
                    pose_overrides: list[str] | None = None,
                    pipeline_overrides: list[str] | None = None, pose_workers: int = 0,
                    background: int = 0) -> Iterator[tuple[object, FrameOutput]]:
    """Run core.pipeline on every frame of ``split`` (both camera splits when ``two_view``).

    Args:
        templates, classifier: model files (the classifier may be None with
            ``oracle='boxes+classes'``).
        oracle: ``none`` (localiser and classifier run), ``boxes`` (ground-truth boxes) or
            ``boxes+classes`` (ground-truth boxes and classes).
        limit: at most this many frames.
        pose_overrides, pipeline_overrides: ``NAME=VALUE`` overrides of PoseParams and of
            the stage dataclasses' fields (LocaliseParams, ClassifyParams, FitParams).
        pose_workers: fit parts in this many worker processes besides this one.
        background: with ``oracle='boxes'``, this many random background boxes per frame in
            the scored view (:func:`background_boxes`, seeded) go through the classifier and
            the pose stage too: :attr:`FrameOutput.background_named` holds their names.
    """
    from tlessbot_ros.core.pipeline import ViewInput
    from tlessbot_ros.core.pose import PoseParams, TemplateDatabase
    from tlessbot_ros.core.recognise import LinearClassifier
    from tlessbot_ros.io.bop import read_split
    from tlessbot_ros.tools.support.overrides import apply_overrides, stage_overrides

    templates_path = templates
    templates = TemplateDatabase.load(templates_path)
    classifier = LinearClassifier.load(classifier) if classifier else None
    views = (TOP, SIDE) if two_view else (SIDE,)
    splits = {v: f'test_{v}' for v in views} if two_view else {SIDE: split}
    readers = {v: read_split(dataset, splits[v], limit=limit) for v in views}
    # Empty-table images (``tlessbot simulate --backgrounds``) feed background subtraction.
    backgrounds = {v: read_split(dataset, f'background_{v}', limit=limit, load_masks=False)
                   for v in views if (dataset / f'background_{v}').is_dir()}
    pose_params = apply_overrides(PoseParams(), pose_overrides)
    stage_params = stage_overrides(pipeline_overrides)
    if oracle == 'boxes+classes':
        # the classes are the truth: nothing for the look-alike check to correct
        stage_params['fit_params'] = replace(stage_params['fit_params'], lookalike_check=False)
    workers = _pose_workers(templates_path, pose_params, stage_params['fit_params'],
                            pose_workers)
    rng = np.random.default_rng(0)
    try:
        pipeline = None
        for images in zip(*readers.values()):
            by_view = dict(zip(views, images))
            empty = {v: next(reader).rgb for v, reader in backgrounds.items()}
            _check_frame(dataset, images, by_view[SIDE], two_view)
            inputs = {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera,
                                   background=empty.get(v))
                      for v, im in by_view.items()}
            if pipeline is None:
                pipeline = _first_pipeline(by_view, classifier=classifier, templates=templates,
                                           pose=pose_params, **stage_params)
            output = FrameOutput()
            t0 = time.perf_counter()
            if oracle == 'none':
                detections = _whole_pipeline(pipeline, inputs, workers, output)
            else:
                detections = _oracle_pipeline(pipeline, by_view, inputs, oracle, workers,
                                              output, t0)
                if background and oracle == 'boxes':
                    output.background_named = _background_names(
                        pipeline, by_view[SIDE], inputs[SIDE], workers, rng, background)
            _add_poses(output, pipeline, detections, by_view, t0)
            yield by_view[SIDE], output
    finally:
        if workers is not None:
            workers.close()


def _pose_workers(templates_path: Path, pose_params, fit_params, count: int):
    """A started pool of ``count`` pose worker processes (None for 0)."""
    if count <= 0:
        return None
    from tlessbot_ros.parallel.pose_pool import PoseWorkerParams, PoseWorkerPool

    workers = PoseWorkerPool(templates_path, pose=pose_params, fit=fit_params,
                             params=PoseWorkerParams(count=count))
    if not workers.wait_ready():
        workers.close()
        raise TlessbotError(f'pose workers did not start: {"; ".join(workers.errors)}')
    return workers


def two_view_frames(scenes: Path, frames: Collection[int] | None = None
                    ) -> Iterator[tuple[dict, dict]]:
    """Each frame of a two-view dataset (``test_top`` and ``test_side``), or those whose image
    id is in ``frames``: (the BOP images by view, the pipeline's ``ViewInput`` by view)."""
    from tlessbot_ros.core.pipeline import ViewInput
    from tlessbot_ros.io.bop import read_split

    readers = [read_split(scenes, f'test_{view}') for view in (TOP, SIDE)]
    for images in zip(*readers):
        if frames is not None and images[0].im_id not in frames:
            continue
        by_view = dict(zip((TOP, SIDE), images))
        yield by_view, {view: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera)
                        for view, im in by_view.items()}


def _check_frame(dataset: Path, images, scored, two_view: bool) -> None:
    """``DatasetError`` unless the views of one frame are the same image, with extrinsics
    where two views are scored together."""
    keys = {(im.scene_id, im.im_id) for im in images}
    if len(keys) != 1:
        raise DatasetError('test_top and test_side do not hold the same scene/image ids')
    if two_view and any(im.T_world_camera is None for im in images):
        raise DatasetError(f'{dataset}: image {scored.im_id} of scene {scored.scene_id} '
                           'has no cam_R_w2c/cam_t_w2c: two views need extrinsics (the '
                           'top-view poses are scored in the side camera); evaluate '
                           'one view with --split test_side')


def _first_pipeline(by_view: dict, **options):
    """The pipeline for a dataset, its rig from the first frame's extrinsics (if all views
    have them), warmed up."""
    from tlessbot_ros.core.common import CameraMount, Rig
    from tlessbot_ros.core.pipeline import PerceptionPipeline

    rig = None
    if all(im.T_world_camera is not None for im in by_view.values()):
        rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                   for v, im in by_view.items()})
    pipeline = PerceptionPipeline(rig=rig, **options)
    # every object's caches now, as a node does at start: the stage times are then those of
    # a running graph, not of the first sight of each object
    pipeline.warm_up()
    return pipeline


def _whole_pipeline(pipeline, inputs: dict, workers, output: FrameOutput) -> list:
    """Localiser, classifier and poses on one frame; the side view's boxes with their class
    go into ``output``."""
    from tlessbot_ros.core.common import mask_box

    result = pipeline.process(inputs, fitter=workers)
    output.timings_ms.update(result.timings_ms)
    output.classified = True
    # a frame without depth is localised and classified from colour alone: no pose to score
    output.pose_ran = all(_has_depth(view) for view in inputs.values())
    output.boxes = []
    side_labels = result.labels.get(SIDE)
    output.labels = side_labels
    by_instance = {d.instance_id: d.obj_id for d in result.detections}
    if side_labels is not None:
        for instance in np.unique(side_labels):
            if instance == 0:
                continue
            box = mask_box(side_labels == instance)
            output.boxes.append((*box, int(by_instance.get(int(instance), 0))))
    return result.detections


def _oracle_pipeline(pipeline, by_view: dict, inputs: dict, oracle: str, workers,
                     output: FrameOutput, t0: float) -> list:
    """Poses on ground-truth boxes, the classes the classifier's (``boxes``) or the truth
    (``boxes+classes``)."""
    labels = oracle_labels(by_view)
    if oracle == 'boxes+classes':
        classes = {k + 1: gt.obj_id for k, gt in enumerate(by_view[SIDE].gt)}
    else:
        t1 = time.perf_counter()
        guesses = pipeline.classify({v: im.rgb for v, im in by_view.items()}, labels,
                                    views=inputs)
        output.timings_ms['classification'] = 1e3 * (time.perf_counter() - t1)
        classes = {i: g.candidates for i, g in guesses.items()}
    t2 = time.perf_counter()
    # RGB-only frames (or depth on some frames only): no pose, the rest is scored
    output.pose_ran = all(_has_depth(im) for im in by_view.values())
    detections = pipeline.estimate_poses(inputs, labels, classes, box_mode=True,
                                         fitter=workers) if output.pose_ran else []
    if oracle == 'boxes':  # the class after verification by the pose fit
        output.classifier_by_gt = {i - 1: (g.obj_id, g.margin) for i, g in guesses.items()}
        output.classes_by_gt = {i - 1: g.obj_id for i, g in guesses.items()}
        output.classes_by_gt.update({d.instance_id - 1: d.obj_id for d in detections})
    if output.pose_ran:
        output.timings_ms['pose'] = 1e3 * (time.perf_counter() - t2)
    output.timings_ms['frame'] = 1e3 * (time.perf_counter() - t0)
    return detections


def _background_names(pipeline, image, view, workers, rng, count: int) -> list[int]:
    """Cut ``count`` random boxes away from the parts of the scored view (``image``, its
    ``view`` input) and name them as a part is named: classifier, then the pose stage where
    the frame has depth (0 = unknown). They get a label image of their own, so that they
    neither cut nor merge the parts' regions (nor take part in their fragment check)."""
    parts = [gt.bbox_visib for gt in image.gt if gt.bbox_visib is not None]
    boxes = background_boxes(rng, parts, image.rgb.shape[:2], count)
    labels = {SIDE: box_labels(image.rgb.shape[:2], boxes)}
    guesses = pipeline.classify({SIDE: image.rgb}, labels, views={SIDE: view})
    names = {i: g.obj_id for i, g in guesses.items()}
    if _has_depth(image):
        detections = pipeline.estimate_poses({SIDE: view}, labels,
                                             {i: g.candidates for i, g in guesses.items()},
                                             box_mode=True, fitter=workers)
        names.update({d.instance_id: d.obj_id for d in detections})
    return [names.get(j + 1, 0) for j in range(len(boxes))]


def box_labels(shape: tuple[int, int], boxes) -> np.ndarray:
    """(H, W) uint16 label image of (x, y, w, h) ``boxes``: box k is instance k + 1, larger
    boxes painted first (a small one stays visible inside a large one)."""
    label = np.zeros(shape, np.uint16)
    for k in sorted(range(len(boxes)), key=lambda k: -boxes[k][2] * boxes[k][3]):
        x, y, w, h = boxes[k]
        label[y:y + h, x:x + w] = k + 1
    return label


def _add_poses(output: FrameOutput, pipeline, detections: list, by_view: dict,
               t0: float) -> None:
    """The frame's per-part and table-plane times and its poses, in the side camera."""
    scored = by_view[SIDE]
    fitted = sum(d.n_points >= pipeline.fit_params.min_roi_points for d in detections)
    if fitted and 'pose' in output.timings_ms:
        output.timings_ms['pose_per_part'] = output.timings_ms['pose'] / fitted
    tables = [pipeline.table_frames[v] for v in by_view if v in pipeline.table_frames]
    if any(t.observed is not None for t in tables):
        output.timings_ms['table_plane'] = sum(t.find_ms for t in tables)
    frame_s = output.timings_ms.get('frame', 1e3 * (time.perf_counter() - t0)) / 1e3
    for d in detections:
        if d.pose is None:
            continue
        T = d.pose.T_camera_object
        if d.view != SIDE:
            src = by_view[d.view]
            T = np.linalg.inv(scored.T_world_camera) @ src.T_world_camera @ T
        output.poses.append(BopEstimate(scored.scene_id, scored.im_id, d.obj_id,
                                       float(d.pose.fitness), T, frame_s))


def _has_depth(image) -> bool:
    return image.depth_m is not None and bool(np.any(np.isfinite(image.depth_m)
                                                     & (image.depth_m > 0)))


def oracle_labels(by_view: dict) -> dict[str, np.ndarray]:
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


def bag_cameras(bag: Path) -> dict[str, str]:
    """The rig cameras whose topics ``bag`` holds (the cell YAML's rig), as ``find_cameras``
    returns them."""
    from tlessbot_ros.io.bags import bag_topics
    from tlessbot_ros.io.config import default_config_path
    from tlessbot_ros.tools.support.bag_inputs import find_cameras
    from tlessbot_ros.tools.support.rig import load_rig

    rig = load_rig(default_config_path())
    return find_cameras(list(bag_topics(bag)), list(rig.cameras), bag=str(bag))


def bag_frames(bag: Path, *, classifier: Path | None = None, templates: Path | None = None,
               limit: int | None = None) -> list[tuple[object, FrameOutput]]:
    """Replay a simulated bag through the graph (lock-step) and pair its poses with the bag's
    ground truth, all in the side camera (top-view poses through the rig extrinsics). A bag of
    one camera runs the graph with that camera alone and is scored in it.

    ``classifier`` and ``templates`` default to the packaged models; ``limit`` keeps the
    first frames."""
    from types import SimpleNamespace

    from tlessbot_ros.conversions import camera_info_to_intrinsics, depth_image_to_metres
    from tlessbot_ros.conversions.topics import DEPTH, DEPTH_INFO, camera_topic
    from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_TEMPLATES
    from tlessbot_ros.io.bags import deserialize, read_bag
    from tlessbot_ros.io.config import default_config_path
    from tlessbot_ros.io.ground_truth import read_ground_truth
    from tlessbot_ros.tools.support.graph_run import main_camera, run_graph_on_bag
    from tlessbot_ros.tools.support.rig import load_rig

    config = default_config_path()
    rig = load_rig(config)
    cameras = bag_cameras(bag)
    one_camera = set(cameras) != set(rig.cameras)
    scored = main_camera(list(cameras))   # side, or the bag's one camera
    scored_frame = f'{scored}_color_optical_frame'
    truth = read_ground_truth(bag)
    depth, intrinsics = {}, {}
    for message in read_bag(bag, [camera_topic(scored, DEPTH),
                                  camera_topic(scored, DEPTH_INFO)]):
        msg = deserialize(message)
        if message.msgtype == 'sensor_msgs/msg/Image':
            depth[message.log_time_ns] = depth_image_to_metres(msg)
        else:
            intrinsics[message.log_time_ns] = camera_info_to_intrinsics(msg)
    classifier = classifier or DEFAULT_CLASSIFIER
    templates = templates or DEFAULT_TEMPLATES
    for path in (classifier, templates):
        if not Path(path).is_file():
            raise ModelFileError(f'model file not found: {path}')
    run = run_graph_on_bag(bag, config=config, lockstep=True, ros_args=[
        '-p', f'model_path:={classifier}', '-p', f'templates_path:={templates}'],
        cameras=list(cameras) if one_camera else None)
    poses: dict[int, list[BopEstimate]] = {}
    for pose in run.poses:
        T = pose.T if pose.frame_id.startswith(scored) else rig.T_a_b(SIDE, TOP) @ pose.T
        poses.setdefault(pose.stamp_ns, []).append(BopEstimate(0, 0, pose.obj_id, 1.0, T))
    frames = []
    for index, stamp in enumerate(sorted(truth)[:limit]):
        gt = [SimpleNamespace(obj_id=p.obj_id, visib_fract=p.visib_fract.get(scored, 0.0),
                              bbox_visib=p.bbox_visib.get(scored),
                              T_camera_object=p.T_camera_object[scored_frame])
              for p in truth[stamp] if scored_frame in p.T_camera_object]
        image = SimpleNamespace(scene_id=0, im_id=index, gt=gt, depth_m=depth.get(stamp),
                                intrinsics=intrinsics.get(stamp))
        for estimate in poses.get(stamp, []):
            estimate.im_id = index
        frames.append((image, FrameOutput(poses=poses.get(stamp, []))))
    return frames


def background_boxes(rng, parts, shape, count: int) -> list[tuple[int, int, int, int]]:
    """Up to ``count`` random (x, y, w, h) boxes of an image of ``shape`` (H, W), sizes drawn
    from the ``parts`` boxes (x0.7-1.3), none holding more than 30 % of a part's box."""
    sizes = np.array([b[2:] for b in parts] or [(64, 64)], float)
    height, width = shape
    background = []
    for _ in range(50 * count):
        if len(background) == count:
            break
        w, h = sizes[rng.integers(len(sizes))] * rng.uniform(0.7, 1.3)
        w, h = int(min(max(w, 8), width - 1)), int(min(max(h, 8), height - 1))
        x, y = int(rng.integers(0, width - w)), int(rng.integers(0, height - h))
        if all(covered((x, y, w, h), b) <= 0.3 for b in parts):
            background.append((x, y, w, h))
    return background


def covered(box, part) -> float:
    """Share of ``part``'s box area inside ``box``."""
    x0, y0 = max(box[0], part[0]), max(box[1], part[1])
    x1 = min(box[0] + box[2], part[0] + part[2])
    y1 = min(box[1] + box[3], part[1] + part[3])
    return max(0, x1 - x0) * max(0, y1 - y0) / max(part[2] * part[3], 1)
