"""Why parts miss 5 cm / 5 deg: one row per target part of a two-view BOP dataset.

  PYTHONPATH=. python scripts/miss_breakdown.py --dataset sim_a --models $M [--limit N]
      [--csv rows.csv] [--pipeline-param NAME=VALUE ...] [--pose-param NAME=VALUE ...]

Runs the whole pipeline (as ``tlessbot evaluate --oracle none``: packaged classifier and
templates unless given) and, for every part at least 30 % visible in the side camera (the
targets of evaluate), reads the ground-truth masks (simulate without --no-masks) to say where
it was lost:

* ``loc:missed``: no instance holds half of its visible pixels in the view the pose would use;
* ``loc:split``: its pixels are shared by two instances (the second holds >= 20 %);
* ``loc:merged``: its instance also holds >= 20 % of another part's pixels;
* ``cls``: its instance got another class (or none);
* ``pose``: right class, pose beyond 5 cm / 5 deg;
* ``ok``.

Matching of poses to parts is evaluate's (greedy by score, same class, nearest); the counts
agree with its 5 cm / 5 deg recall.
"""
from __future__ import annotations

import argparse
import csv
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import SIDE, TOP, CameraMount, Rig, mask_box
from tlessbot_ros.core.metrics import is_correct_cm_deg, pose_error
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import PoseParams, TemplateDatabase
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_TEMPLATES
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.io.bop_results import BopEstimate
from tlessbot_ros.tools.support.eval_scoring import (
    MIN_VISIB_FRACT,
    _match_boxes,
    load_scoring_models,
    match_poses,
)
from tlessbot_ros.tools.support.overrides import apply_overrides, stage_overrides


def _border_px(box, width: int, height: int) -> int:
    if box is None or box[2] <= 0:
        return -1
    x, y, w, h = box
    return int(min(x, y, width - (x + w), height - (y + h)))


def _owner(labels: np.ndarray, mask: np.ndarray) -> tuple[int, float, float]:
    """(label holding most of ``mask``, its share, the second label's share)."""
    area = int(mask.sum())
    if area == 0:
        return 0, 0.0, 0.0
    values, counts = np.unique(labels[mask], return_counts=True)
    keep = values != 0
    values, counts = values[keep], counts[keep]
    if len(values) == 0:
        return 0, 0.0, 0.0
    order = np.argsort(-counts)
    second = counts[order[1]] / area if len(order) > 1 else 0.0
    return int(values[order[0]]), counts[order[0]] / area, float(second)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--dataset', type=Path, required=True)
    parser.add_argument('--models', type=Path, required=True)
    parser.add_argument('--classifier', type=Path, default=DEFAULT_CLASSIFIER)
    parser.add_argument('--templates', type=Path, default=DEFAULT_TEMPLATES)
    parser.add_argument('--limit', type=int)
    parser.add_argument('--csv', type=Path)
    parser.add_argument('--pose-param', action='append')
    parser.add_argument('--pipeline-param', action='append')
    args = parser.parse_args(argv)

    templates = TemplateDatabase.load(args.templates)
    classifier = LinearClassifier.load(args.classifier)
    pose_params = apply_overrides(PoseParams(), args.pose_param)
    stages = stage_overrides(args.pipeline_param)
    readers = [read_split(args.dataset, f'test_{v}', limit=args.limit) for v in (TOP, SIDE)]
    models = load_scoring_models(args.models, set(templates.objects))
    rows = []
    pipeline = None
    frames = false_pos = 0
    for top, side in zip(*readers):
        frames += 1
        by_view = {TOP: top, SIDE: side}
        if pipeline is None:
            rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                       for v, im in by_view.items()})
            pipeline = PerceptionPipeline(rig=rig, classifier=classifier, templates=templates,
                                          pose=pose_params, **stages)
        inputs = {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera)
                  for v, im in by_view.items()}
        result = pipeline.process(inputs)
        labels = result.labels
        by_instance = {d.instance_id: d for d in result.detections}
        estimates = []
        T_side_world = np.linalg.inv(side.T_world_camera)
        for d in result.detections:
            if d.pose is None:
                continue
            T = d.pose.T_camera_object
            if d.view != SIDE:
                T = T_side_world @ by_view[d.view].T_world_camera @ T
            estimates.append(BopEstimate(side.scene_id, side.im_id, d.obj_id,
                                         float(d.pose.fitness), T))
        matches = match_poses(side, estimates, models)
        boxes = [mask_box(labels[SIDE] == i) for i in np.unique(labels[SIDE]) if i]
        false_pos += _match_boxes(side, boxes)[1]
        masks = {v: [g.mask for g in im.gt] for v, im in by_view.items()}
        for k, gt in enumerate(side.gt):
            if gt.visib_fract is None or gt.visib_fract < MIN_VISIB_FRACT:
                continue
            gt_top = top.gt[k]
            row = {'scene': side.scene_id, 'im': side.im_id, 'gt': k, 'obj': gt.obj_id,
                   'vis_side': round(gt.visib_fract, 3),
                   'vis_top': round(gt_top.visib_fract or 0.0, 3),
                   'border_side': _border_px(gt.bbox_visib, side.intrinsics.width,
                                             side.intrinsics.height),
                   'border_top': _border_px(gt_top.bbox_visib, top.intrinsics.width,
                                            top.intrinsics.height)}
            owners = {v: _owner(labels[v], masks[v][k]) for v in (SIDE, TOP)
                      if masks[v][k] is not None}
            inst, share, second = owners[SIDE]
            view = SIDE
            if inst == 0 or share < 0.5:
                if owners[TOP][0] and owners[TOP][1] >= 0.5 and \
                        not (labels[SIDE] == owners[TOP][0]).any():
                    inst, share, second = owners[TOP]
                    view = TOP
            merged = False
            if inst:
                region = labels[view] == inst
                area = region.sum()
                for j, other in enumerate(masks[view]):
                    if j != k and other is not None and (region & other).sum() >= 0.2 * area:
                        merged = True
            det = by_instance.get(inst)
            est = matches.get(k)
            err = None
            if est is not None:
                err = pose_error(est.T_camera_object, gt.T_camera_object,
                                 models[gt.obj_id].symmetries)
            ok = err is not None and is_correct_cm_deg(err)
            if ok:
                status = 'ok'
            elif inst == 0 or share < 0.5:
                status = 'loc:missed'
            elif second >= 0.2:
                status = 'loc:split'
            elif merged:
                status = 'loc:merged'
            elif det is None or det.obj_id != gt.obj_id:
                status = 'cls'
            else:
                status = 'pose'
            row.update({
                'status': status, 'inst': inst, 'share': round(float(share), 2),
                'second': round(float(second), 2), 'merged': merged,
                'det_view': det.view if det else '', 'det_obj': det.obj_id if det else 0,
                'rank': det.class_rank if det else -1,
                'n_points': det.n_points if det else 0,
                'fitness': round(det.pose.fitness, 3) if det and det.pose else '',
                'err_cm': round(100 * err.translation_m, 2) if err else '',
                'err_deg': round(err.rotation_deg, 1) if err else '',
            })
            rows.append(row)
    counts = Counter(r['status'] for r in rows)
    n = len(rows)
    print(f'{args.dataset}: {frames} frames, {n} targets, ok {counts["ok"]} '
          f'({counts["ok"] / max(n, 1):.3f}), false positives / frame '
          f'{false_pos / max(frames, 1):.2f}')
    for status, c in sorted(counts.items()):
        print(f'  {status:12s} {c}')
    for r in rows:
        if r['status'] != 'ok':
            print('  ' + ' '.join(f'{k}={v}' for k, v in r.items()))
    if args.csv is not None:
        with open(args.csv, 'w', newline='') as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
    return 0


if __name__ == '__main__':
    sys.exit(main())
