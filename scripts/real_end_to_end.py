"""Where each part of a one-camera BOP set is lost end to end (``evaluate --oracle none``).

    PYTHONPATH=. python scripts/real_end_to_end.py --dataset $D --models $D/models \
        --classifier m.npz --templates T [--overlays DIR] [--pipeline-param NAME=VALUE ...]

Runs the frames as ``tlessbot evaluate --oracle none`` does (``eval_frames.pipeline_frames``)
and, per ground-truth part at least 30 % visible (visible masks ray-cast at the truth where the
set has none, ``eval_scoring.with_visible_masks``), prints the region that holds most of it,
its mask and box IoU, the cause (evaluate's ``eval_breakdown``: not found / merged / split / box
off), the class named and, on frames with depth, the pose error; then detection at box IoU 0.5
and 0.7, top-1 and false positives per frame, for the frames with and without depth apart.
``--overlays DIR`` writes each frame with the regions' outlines (red) and the truth's (green):
derived images of the set, for reading only (never commit them: docs/bench/real-end-to-end.md).
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core.common import SIDE, MeshRenderer
from tlessbot_ros.core.metrics import adds, box_iou, pose_error
from tlessbot_ros.core.pipeline import ViewInput
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.tools.support.eval_frames import _first_pipeline, pipeline_frames
from tlessbot_ros.tools.support.eval_scoring import (
    MIN_VISIB_FRACT,
    load_scoring_models,
    match_poses,
    with_visible_masks,
)


def _matches(gts, boxes, threshold: float) -> dict[int, int]:
    """Greedy box matching at ``threshold`` (as evaluate's at 0.7): {GT index: box index}."""
    pairs = sorted(((box_iou(gt.bbox_visib, box[:4]), k, j) for k, gt in enumerate(gts)
                    if gt.bbox_visib is not None for j, box in enumerate(boxes)), reverse=True)
    matched: dict[int, int] = {}
    for iou, k, j in pairs:
        if iou >= threshold and k not in matched and j not in matched.values():
            matched[k] = j
    return matched


def _cause(k: int, labels: np.ndarray, gts, matched: dict[int, int]) -> str:
    """evaluate's cause of a miss (eval_breakdown.frame_breakdown), or 'found'."""
    if k in matched:
        return 'found'
    mask = gts[k].mask
    ids, counts = np.unique(labels[mask], return_counts=True)
    share = {int(i): c / mask.sum() for i, c in zip(ids, counts) if i}
    if not share or max(share.values()) < 0.2:
        return 'not found'
    best = max(share, key=share.get)
    region = labels == best
    others = sum(np.count_nonzero(region & g.mask) >= max(1, g.mask.sum() / 3)
                 for g in gts if g.mask is not None)
    if others >= 2:
        return 'merged'
    return 'split' if sum(s >= 1 / 6 for s in share.values()) >= 2 else 'box off'


def _ideal_depth(image, models, templates, blur_px: float) -> np.ndarray:
    """(H, W) float mm: the table plane found in ``image``'s depth, the parts ray-cast at
    their ground-truth poses on it, Gaussian-blurred by ``blur_px`` (0: sharp)."""
    from tlessbot_ros.core.pose import TemplateDatabase
    pipeline = _first_pipeline({SIDE: image}, classifier=None,
                               templates=TemplateDatabase.load(templates))
    T = pipeline.table_frame(SIDE, ViewInput(image.rgb, image.depth_m, image.intrinsics,
                                             image.T_world_camera)).T_world_camera
    K, (height, width) = image.intrinsics.K, image.depth_m.shape
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    along = T[2, 0] * (u - K[0, 2]) / K[0, 0] + T[2, 1] * (v - K[1, 2]) / K[1, 1] + T[2, 2]
    depth = -T[2, 3] / along
    renderer = MeshRenderer()
    for gt in image.gt:
        renderer.add_mesh(models[gt.obj_id].vertices, models[gt.obj_id].faces,
                          gt.T_camera_object)
    rendered = renderer.render(image.intrinsics, np.eye(4))
    parts = rendered.instance >= 0
    depth[parts] = rendered.depth_m[parts]
    if blur_px > 0:
        depth = cv2.GaussianBlur(depth, (0, 0), blur_px)
    return 1e3 * depth


def _with_ideal_depth(dataset: Path, split: str, models_dir: Path, templates: Path,
                      blur_px: float, out: Path) -> Path:
    """A copy of ``dataset`` in ``out`` whose depth images are :func:`_ideal_depth`'s."""
    shutil.copytree(dataset, out, dirs_exist_ok=True)
    models = None
    for image in read_split(dataset, split):
        if image.depth_m is None:
            continue
        models = models or load_scoring_models(models_dir, {gt.obj_id for gt in image.gt})
        path = out / split / f'{image.scene_id:06d}' / 'depth' / f'{image.im_id:06d}.png'
        depth = _ideal_depth(image, models, templates, blur_px)
        cv2.imwrite(str(path), np.rint(depth / image.depth_scale).astype(np.uint16))
    return out


def _overlay(path: Path, image, labels: np.ndarray) -> None:
    picture = cv2.cvtColor(image.rgb, cv2.COLOR_RGB2BGR)
    for gt in image.gt:
        contours, _ = cv2.findContours(gt.mask.astype(np.uint8), cv2.RETR_EXTERNAL,
                                       cv2.CHAIN_APPROX_NONE)
        cv2.drawContours(picture, contours, -1, (0, 255, 0), 1)
    for instance in np.unique(labels):
        if instance:
            contours, _ = cv2.findContours((labels == instance).astype(np.uint8),
                                           cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            cv2.drawContours(picture, contours, -1, (0, 0, 255), 1)
    cv2.imwrite(str(path), picture)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True)
    parser.add_argument('--models', type=Path, required=True)
    parser.add_argument('--classifier', type=Path, required=True)
    parser.add_argument('--templates', type=Path, required=True,
                        help="templates.npz (evaluate's: the parts cache it names)")
    parser.add_argument('--split', default='test')
    parser.add_argument('--overlays', type=Path)
    parser.add_argument('--pipeline-param', action='append', metavar='NAME=VALUE')
    parser.add_argument('--ideal-depth', type=float, metavar='BLUR_PX',
                        help="replace each depth image by the truth's: the table plane and "
                             'the parts ray-cast at their poses, blurred by BLUR_PX (0: sharp)')
    parser.add_argument('--no-depth', action='store_true', help='colour alone on every frame')
    args = parser.parse_args()
    work = tempfile.TemporaryDirectory()
    if args.ideal_depth is not None:
        args.dataset = _with_ideal_depth(args.dataset, args.split, args.models, args.templates,
                                         args.ideal_depth, Path(work.name) / 'set')
    elif args.no_depth:
        shutil.copytree(args.dataset, Path(work.name) / 'set', ignore=shutil.ignore_patterns(
            'depth'))
        args.dataset = Path(work.name) / 'set'
    frames = pipeline_frames(args.dataset, args.split, False, templates=args.templates,
                             classifier=args.classifier,
                             pipeline_overrides=args.pipeline_param)
    models = None
    tally: dict[bool, Counter] = {True: Counter(), False: Counter()}
    print('| frame | part | obj | visible px | region: share, mask IoU, box IoU | cause | named '
          '| pose: mm, deg, ADD-S / d |\n' + '|---' * 8 + '|')
    for image, output in frames:
        if models is None:
            models = load_scoring_models(args.models, {gt.obj_id for gt in image.gt})
        image = with_visible_masks(image, models)
        labels, boxes = output.labels, output.boxes
        at = {t: _matches(image.gt, boxes, t) for t in (0.5, 0.7)}
        poses = match_poses(image, output.poses, models) if output.pose_ran else {}
        count = tally[output.pose_ran]
        count['frames'] += 1
        count['false_pos'] += sum(j not in at[0.7].values() and boxes[j][4] != 0
                                  for j in range(len(boxes)))
        for k, gt in enumerate(image.gt):
            if (gt.visib_fract or 0) < MIN_VISIB_FRACT:
                continue
            ids, counts = np.unique(labels[gt.mask], return_counts=True)
            best = int(ids[np.argmax(np.where(ids > 0, counts, -1))]) if ids.any() else 0
            share = np.count_nonzero(labels[gt.mask] == best) / gt.mask.sum() if best else 0
            region = labels == best
            mask_iou = np.count_nonzero(region & gt.mask) / np.count_nonzero(region | gt.mask)
            j = next((j for j, i in enumerate(i for i in np.unique(labels) if i) if i == best),
                     None)
            box = box_iou(gt.bbox_visib, boxes[j][:4]) if best and j is not None else 0.0
            cause = _cause(k, labels, image.gt, at[0.7])
            named = boxes[at[0.5][k]][4] if k in at[0.5] else '-'
            count['parts'] += 1
            count['iou05'] += k in at[0.5]
            count['iou07'] += k in at[0.7]
            for t in at:   # top-1 of the parts found at each IoU
                count[f'top1_of{t}'] += k in at[t]
                count[f'top1{t}'] += k in at[t] and boxes[at[t][k]][4] == gt.obj_id
            count[cause] += 1
            pose = '-'
            if k in poses:
                error = pose_error(poses[k].T_camera_object, gt.T_camera_object,
                                   models[gt.obj_id].symmetries)
                adds_d = adds(poses[k].T_camera_object, gt.T_camera_object,
                              models[gt.obj_id].vertices) / models[gt.obj_id].diameter_m
                pose = f'{1e3 * error.translation_m:.0f}, {error.rotation_deg:.0f}, {adds_d:.2f}'
            print(f'| {image.im_id} | {k} | {gt.obj_id} | {int(gt.mask.sum())} | {share:.2f}, '
                  f'{mask_iou:.2f}, {box:.2f} | {cause} | {named} | {pose} |')
        if args.overlays:
            args.overlays.mkdir(parents=True, exist_ok=True)
            _overlay(args.overlays / f'{image.im_id:06d}.png', image, labels)
    print('\n| frames | parts | IoU >= 0.5 | IoU >= 0.7 | top-1 (of found at 0.5; 0.7) '
          '| false pos / frame | not found | merged | split | box off |\n' + '|---' * 10 + '|')
    for depth, c in tally.items():
        if c['frames']:
            print(f"| {'with' if depth else 'without'} depth: {c['frames']} | {c['parts']} | "
                  f"{c['iou05'] / c['parts']:.3f} | {c['iou07'] / c['parts']:.3f} | "
                  f"{c['top10.5'] / max(c['top1_of0.5'], 1):.3f} ({c['top1_of0.5']}); "
                  f"{c['top10.7'] / max(c['top1_of0.7'], 1):.3f} ({c['top1_of0.7']}) | "
                  f"{c['false_pos'] / c['frames']:.2f} | {c['not found']} | {c['merged']} | "
                  f"{c['split']} | {c['box off']} |")


if __name__ == '__main__':
    main()
