"""Every false positive of a two-view BOP set, with what it lies on and which stage made it.

  PYTHONPATH=. python scripts/false_positives.py --dataset SCENES --classifier C \
      --templates T [--frames 5,12]

Runs the whole pipeline on each frame (as ``tlessbot evaluate --oracle none``) and, for each
box of the side view that matches no part (IoU >= 0.7, evaluate's greedy matching), prints
its class, its pixels, the ground-truth parts it overlaps (whether another box matched them)
and where its region came from: the fusion (``split``: a side blob divided because the top
saw several blobs; its top and side pixels), a piece the pose stage divided off
(``core/two_parts.py``: an id the fusion did not give), or a fusion region the pose stage
changed (a division's rest, a joined piece: its pixels before and after).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def _matched(image, boxes) -> dict[int, int]:
    from tlessbot_ros.core.metrics import box_iou
    pairs = [(box_iou(gt.bbox_visib, box[:4]), k, j) for k, gt in enumerate(image.gt)
             if gt.bbox_visib is not None and gt.bbox_visib[2] > 0
             for j, box in enumerate(boxes)]
    matched: dict[int, int] = {}
    for iou, k, j in sorted(pairs, reverse=True):
        if iou >= 0.7 and k not in matched and j not in matched.values():
            matched[k] = j
    return matched


def _origin(instance: int, fused: dict, before: np.ndarray, after: np.ndarray) -> str:
    if instance not in fused:
        return 'a piece the pose stage divided off'
    inst = fused[instance]
    text = f'fusion (top {inst.area_top} px, side {inst.area_side} px, split={inst.split})'
    n0, n1 = int((before == instance).sum()), int((after == instance).sum())
    return text + ('' if n0 == n1 else f'; pose stage changed it: {n0} -> {n1} px')


def describe(image, labels: np.ndarray, detections, before: np.ndarray, fused: dict
             ) -> list[str]:
    """The lines of one frame's false positives (``labels``: the side view's after the pose
    stage, ``before``: the fusion's)."""
    ids = [int(i) for i in np.unique(labels) if i]
    named = {d.instance_id: d.obj_id for d in detections}
    boxes = [(*_box(labels == i), named.get(i, 0)) for i in ids]
    matched = _matched(image, boxes)
    lines = []
    for j, instance in enumerate(ids):
        if j in matched.values():
            continue
        mask = labels == instance
        on = sorted(((int((mask & gt.mask).sum()), k) for k, gt in enumerate(image.gt)
                     if gt.mask is not None and (mask & gt.mask).any()), reverse=True)
        parts = ', '.join(f'{n} px of obj {image.gt[k].obj_id} '
                          f'({"matched by another box" if k in matched else "not matched"})'
                          for n, k in on[:3]) or 'no part'
        lines.append(f'frame {image.im_id}: named {boxes[j][4]}, {int(mask.sum())} px on '
                     f'{parts}; {_origin(instance, fused, before, labels)}')
    return lines


def _box(mask: np.ndarray) -> tuple[int, int, int, int]:
    from tlessbot_ros.core.common import mask_box
    return mask_box(mask)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--dataset', type=Path, required=True)
    parser.add_argument('--classifier', type=Path, required=True)
    parser.add_argument('--templates', type=Path, required=True)
    parser.add_argument('--frames', help='comma-separated image ids (default: all)')
    args = parser.parse_args()
    from tlessbot_ros.core.common import CameraMount, Rig
    from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
    from tlessbot_ros.core.pose import TemplateDatabase
    from tlessbot_ros.core.recognise import LinearClassifier
    from tlessbot_ros.io.bop import read_split

    wanted = None if not args.frames else {int(f) for f in args.frames.split(',')}
    pipeline: PerceptionPipeline | None = None
    total = 0
    for top, side in zip(read_split(args.dataset, 'test_top'),
                         read_split(args.dataset, 'test_side')):
        if wanted is not None and side.im_id not in wanted:
            continue
        by_view = {'top': top, 'side': side}
        if pipeline is None:   # the rig from the first frame's extrinsics, as evaluate
            rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                       for v, im in by_view.items()})
            pipeline = PerceptionPipeline(rig=rig, classifier=LinearClassifier.load(
                args.classifier), templates=TemplateDatabase.load(args.templates))
        views = {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera)
                 for v, im in by_view.items()}
        fusion = pipeline.localise(views)
        before = fusion.labels['side'].copy()
        guesses = pipeline.classify({v: views[v].rgb for v in views}, fusion.labels,
                                    views=views)
        detections = pipeline.estimate_poses(views, fusion.labels,
                                             {i: g.candidates for i, g in guesses.items()})
        lines = describe(side, fusion.labels['side'], detections, before,
                         {i.instance_id: i for i in fusion.instances})
        total += len(lines)
        for line in lines:
            print(line)
    print(f'{total} false positives')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
