"""Per crop of a real BOP set with depth: what the pose stage's verification and search do.

For each ground-truth box of the frames with depth (docs/bench/real-pose.md, section 2):

- ``--classifier``: the classifier's candidates, each fitted as the verification fits them
  (table path, unpolished) with its value (``part_fit._verify_value``), and the class the
  pose stage names;
- without: the true class fitted on the box (as ``evaluate --oracle boxes+classes``), its
  ADD-S (share of the diameter) against the depth optimum near the ground truth (ICP from the
  ground truth on the part's own rendered pixels) and against the ground truth, and both
  poses' fitness and coverage on the box;
- ``--steps``: the true class fitted on the box, its error against the depth optimum after each
  step of the pose stage (the fit, the flat parts' and look-alike checks, the resting prior,
  the near-symmetric turns) and the final pose's against the truth (translation, rotation,
  ADD-S / d, VSD), each box's estimate scored against its own part (docs/bench/
  real-pose-gap.md).

    PYTHONPATH=. python scripts/real_pose_crops.py --dataset $D --templates T [--classifier M]
    PYTHONPATH=. python scripts/real_pose_crops.py --dataset $D --templates T --steps
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

import tlessbot_ros.core.pipeline as pipeline_module
from tlessbot_ros.core.common import SIDE, MeshRenderer, transform_points
from tlessbot_ros.core.metrics import adds, pose_error, vsd
from tlessbot_ros.core.part_fit import _verify_sample, _verify_value
from tlessbot_ros.core.pipeline import ViewInput
from tlessbot_ros.core.pose import TemplateDatabase, roi_cloud
from tlessbot_ros.core.pose.resting import RestingParams, level_starts
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.io.models import read_mesh
from tlessbot_ros.tools.support.eval_frames import _first_pipeline, oracle_labels
from tlessbot_ros.tools.support.eval_scoring import load_scoring_models
from tlessbot_ros.tools.support.overrides import stage_overrides

STEPS = ('fit', 'checks', 'rest', 'turns')


def _adds(T_a: np.ndarray, T_b: np.ndarray, points: np.ndarray) -> float:
    return float(cKDTree(transform_points(T_b, points)).query(
        transform_points(T_a, points))[0].mean())


def _box_points(pipeline, image, labels, instance, T_world_camera) -> np.ndarray:
    points = roi_cloud(image.depth_m, labels == instance, image.intrinsics).astype(np.float64)
    height = transform_points(T_world_camera, points)[:, 2]
    return points[height > pipeline.fit_params.table_clearance_m]


def _verification(pipeline, image, view, labels, T_world_camera, name) -> None:
    estimator = pipeline.pose_estimator
    guesses = pipeline.classify({SIDE: image.rgb}, {SIDE: labels}, views={SIDE: view})
    found = {d.instance_id: d for d in pipeline.estimate_poses(
        {SIDE: view}, {SIDE: labels}, {i: g.candidates for i, g in guesses.items()},
        box_mode=True)}
    for instance, guess in sorted(guesses.items()):
        points = _box_points(pipeline, image, labels, instance, T_world_camera)
        sample = _verify_sample(points, pipeline.fit_params)
        values = []
        for obj_id in guess.candidates:
            result = estimator.estimate(points, obj_id, T_world_camera=T_world_camera,
                                        fallback=False, polish=False)
            value = None if result.best is None else _verify_value(
                estimator, pipeline.fit_params, sample, obj_id, result.best)
            values.append(f'{name(obj_id)} ' + ('none' if value is None else f'{value:.2f}'))
        named = found[instance].obj_id if instance in found else guess.obj_id
        print(f'| {image.im_id}, {instance} | {name(image.gt[instance - 1].obj_id)} '
              f'| {", ".join(values)} | {name(named)} |')


def _search(pipeline, image, view, labels, T_world_camera, meshes, name) -> list[bool]:
    estimator, database = pipeline.pose_estimator, pipeline.pose_estimator.database
    renderer = MeshRenderer()
    for gt in image.gt:
        renderer.add_mesh(*meshes[gt.obj_id], gt.T_camera_object)
    rendered = renderer.render(image.intrinsics, np.eye(4))
    found = {d.instance_id: d for d in pipeline.estimate_poses(
        {SIDE: view}, {SIDE: labels}, {k + 1: gt.obj_id for k, gt in enumerate(image.gt)},
        box_mode=True)}
    near = []
    for k, gt in enumerate(image.gt):
        obj, detection = database[gt.obj_id], found.get(k + 1)
        own = roi_cloud(image.depth_m, rendered.instance == k, image.intrinsics)
        if len(own) < 30 or detection is None or detection.pose is None:
            print(f'| {image.im_id}, {k + 1} | {name(gt.obj_id)} | no pose | | | |')
            continue
        scene = estimator._prepare(own.astype(np.float64), obj, 1.0, {})
        T_opt = estimator.refiner.icp_batch(scene, obj, gt.T_camera_object[None],
                                            iterations=30, points=len(scene))[0]
        box = estimator._prepare(_box_points(pipeline, image, labels, k + 1, T_world_camera),
                                 obj, estimator.params.table_voxel_scale, {})
        ours, best = (estimator.refiner.evaluate(box, obj, T, method='table')
                      for T in (detection.pose.T_camera_object, T_opt))
        model = obj.model_points.astype(np.float64)
        to_opt = _adds(detection.pose.T_camera_object, T_opt, model) / obj.diameter_m
        to_gt = _adds(detection.pose.T_camera_object, gt.T_camera_object, model) / obj.diameter_m
        near.append((to_opt < 0.1, to_gt < 0.1))
        own_share = np.mean(rendered.instance[labels == k + 1] == k)
        print(f'| {image.im_id}, {k + 1} | {name(gt.obj_id)} | {to_opt:.2f} / {to_gt:.2f} '
              f'| {ours.fitness:.2f} / {ours.coverage:.2f} | {best.fitness:.2f} / '
              f'{best.coverage:.2f} | {own_share:.2f} |')
    return near


def _traced(pipeline) -> dict:
    """{instance: {step: T_camera_object}} filled as ``pipeline.estimate_poses`` runs: the
    pose after each step (the module's step functions wrapped, this process only)."""
    from tlessbot_ros.core import resting_check

    trace: dict = {}

    def keep(job, step):
        pose = job.detection.pose
        trace.setdefault(job.detection.instance_id, {})[step] = \
            None if pose is None else pose.T_camera_object.copy()

    fit, checks = pipeline.fit_part, pipeline_module.check_fitted_part

    def fit_part(job):
        fit(job)
        keep(job, 'fit')

    def checked(p, job, views, labels):
        checks(p, job, views, labels)
        keep(job, 'checks')

    def rest_and_turns(p, job, views, labels):
        resting_check.check_resting(p, job, views, labels)
        keep(job, 'rest')
        before = job.detection.pose
        resting_check.check_turns(p, job, views, labels)
        if job.detection.pose is not before:
            resting_check.check_resting(p, job, views, labels)
        keep(job, 'turns')

    pipeline.fit_part = fit_part
    pipeline_module.check_fitted_part = checked
    pipeline_module.check_resting_and_turns = rest_and_turns
    return trace


def _steps(pipeline, trace, image, view, labels, T_world_camera, models, optimum) -> list:
    """One row per part of ``image``: its pose against the depth optimum after each step and
    the final one against the truth; returns the final pose's (5 cm / 5°, VSD, ADD-S) hits."""
    trace.clear()
    pipeline.estimate_poses({SIDE: view}, {SIDE: labels},
                            {k + 1: gt.obj_id for k, gt in enumerate(image.gt)}, box_mode=True)
    hits = []
    for k, gt in enumerate(image.gt):
        model, poses = models[gt.obj_id], trace.get(k + 1, {})
        T_opt = optimum.get((image.im_id, k))

        def error(T, T_ref, model=model):
            if T is None or T_ref is None:
                return None
            e = pose_error(T, T_ref, model.symmetries)
            return (1e3 * e.translation_m, e.rotation_deg,
                    adds(T, T_ref, model.vertices) / model.diameter_m)

        def text(e):
            return '-' if e is None else f'{e[0]:.0f} mm {e[1]:.0f}° {e[2]:.2f}'

        final = poses.get('turns')
        to_gt = error(final, gt.T_camera_object)
        value = None if final is None else vsd(final, gt.T_camera_object, image.depth_m,
                                               image.intrinsics, model.renderer)[0]
        hits.append((to_gt is not None and to_gt[0] < 50 and to_gt[1] < 5,
                     value is not None and value < 0.3, to_gt is not None and to_gt[2] < 0.1))
        rest = '' if poses.get('fit') is None else \
            '{rest_tilt_deg:.0f}° {rest_contact_m:+.3f} m'.format(**level_starts(
                pipeline.pose_estimator.database[gt.obj_id],
                T_world_camera @ poses['fit'], RestingParams())[1])
        steps = ' | '.join(text(error(poses.get(s), T_opt)) for s in STEPS)
        optimum_to_gt = text(error(T_opt, gt.T_camera_object))
        print(f'| {image.im_id}, {k + 1} | obj_{gt.obj_id:02d} | {optimum_to_gt} | {steps} '
              f'| {text(to_gt)} | {"-" if value is None else f"{value:.2f}"} | {rest} |')
    return hits


def _rendered(image, meshes):
    """Every ground-truth part ray-cast at its pose (``instance`` k = GT k, -1 none)."""
    renderer = MeshRenderer()
    for gt in image.gt:
        renderer.add_mesh(*meshes[gt.obj_id], gt.T_camera_object)
    return renderer.render(image.intrinsics, np.eye(4))


def _optimum(pipeline, image, meshes) -> dict:
    """{(im_id, GT index): the depth optimum}: ICP from the truth on the part's own visible
    pixels (as scripts/real_pose_diagnosis.py)."""
    estimator = pipeline.pose_estimator
    rendered = _rendered(image, meshes)
    out = {}
    for k, gt in enumerate(image.gt):
        own = roi_cloud(image.depth_m, rendered.instance == k, image.intrinsics)
        if len(own) >= 30:
            obj = estimator.database[gt.obj_id]
            scene = estimator._prepare(own.astype(np.float64), obj, 1.0, {})
            out[image.im_id, k] = estimator.refiner.icp_batch(
                scene, obj, gt.T_camera_object[None], iterations=30, points=len(scene))[0]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True)
    parser.add_argument('--templates', type=Path, required=True)
    parser.add_argument('--classifier', type=Path)
    parser.add_argument('--steps', action='store_true',
                        help='the error after each step of the pose stage (true classes)')
    parser.add_argument('--pipeline-param', action='append', metavar='NAME=VALUE',
                        help='a pipeline setting, as `tlessbot evaluate --pipeline-param`')
    parser.add_argument('--masks', action='store_true',
                        help="with --steps: each part's own visible pixels (the truth "
                             'ray-cast) instead of its box')
    parser.add_argument('--split', default='test')
    parser.add_argument('--units', type=float, default=1e-3, help='model units, m (mm: 1e-3)')
    args = parser.parse_args()
    database = TemplateDatabase.load(args.templates)
    classifier = LinearClassifier.load(args.classifier) if args.classifier else None
    meshes = {}
    for obj_id in database.objects:
        vertices, faces = read_mesh(args.dataset / 'models' / f'obj_{obj_id:06d}.ply')
        meshes[obj_id] = (vertices * args.units, faces)

    def name(obj_id: int) -> str:
        return f'obj_{obj_id:02d}'

    models = load_scoring_models(args.dataset / 'models', set(database.objects))
    if args.steps:
        print('| frame, box | truth | optimum to GT | ' + ' | '.join(STEPS) + ' (to the optimum: '
              'mm, deg, ADD-S / d) | final to GT | VSD | fit: tilt from a stable pose, lowest '
              'point |\n' + '|---' * 10 + '|')
    elif classifier is not None:
        print('| frame, box | truth | candidates: value | named |\n|---|---|---|---|')
    else:
        print('| frame, box | truth | ADD-S / d to optimum / to GT | ours on the box: fitness / '
              'coverage | optimum on the box | own pixels in the box |\n|---|---|---|---|---|---|')
    pipeline, near, trace, hits = None, [], {}, []
    for image in read_split(args.dataset, args.split):
        if image.depth_m is None:
            continue
        if pipeline is None:
            pipeline = _first_pipeline({SIDE: image}, classifier=classifier, templates=database,
                                       **stage_overrides(args.pipeline_param))
            trace = _traced(pipeline) if args.steps else trace
        view = ViewInput(image.rgb, image.depth_m, image.intrinsics, image.T_world_camera)
        labels = oracle_labels({SIDE: image})[SIDE]
        T_world_camera = pipeline.table_frame(SIDE, view).T_world_camera
        if args.masks:
            labels = (_rendered(image, meshes).instance + 1).astype(np.uint16)
        if args.steps:
            hits += _steps(pipeline, trace, image, view, labels, T_world_camera, models,
                           _optimum(pipeline, image, meshes))
        elif classifier is not None:
            _verification(pipeline, image, view, labels, T_world_camera, name)
        else:
            near += _search(pipeline, image, view, labels, T_world_camera, meshes, name)
    if hits:
        share = np.mean(hits, axis=0)
        print(f'\n{len(hits)} parts, each box scored against its own part: 5 cm / 5° '
              f'{share[0]:.3f}, VSD < 0.3 {share[1]:.3f}, ADD-S < 0.1 d {share[2]:.3f}')
    if near:
        share = np.mean(near, axis=0)
        print(f'\n{len(near)} parts fitted: within 0.1 d of the depth optimum {share[0]:.2f}, '
              f'of the ground truth {share[1]:.2f}')


if __name__ == '__main__':
    main()
