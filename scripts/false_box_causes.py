"""Every false box of a ``tlessbot evaluate`` run, with its cause and what made the box wrong.
docs/bench/smoothed-false-parts-left.md.

    python scripts/false_box_causes.py TSV -- EVALUATE ARGUMENTS...

Runs ``tlessbot evaluate`` with the given arguments and, for every box of the scored view that
matches no part, writes one row to TSV (and the scored view's labels of every frame to
TSV's name with ``_labels.npz``): frame, `evaluate`'s cause (``eval_breakdown``), the
class named and the class of the part it lies on, its pixels, the share of that part's visible
pixels it holds (``cover``), the share of its own pixels off that part (``spill``; of those,
the share on other parts, ``spill_on_parts``), its box's IoU with the part's visible box and
its area over that box's (``box_ratio``), the largest share of the part another instance
holds (``other_share``) and whether the part is matched by another box. A piece of a part is
then put in one finer cause (``detail``):

* ``split``: another instance holds a sixth of the part too;
* ``fattened``: it holds most of the part (``cover`` >= 0.8) and its box is larger;
* ``shrunk``: it holds most of what it covers on the part but its box is smaller;
* ``duplicate``: the part is matched by another box (a second box on a found part).
"""
from __future__ import annotations

import sys

import numpy as np

from tlessbot_ros.core.metrics import box_iou
from tlessbot_ros.tools.support import eval_scoring

COLUMNS = ('frame', 'cause', 'detail', 'named', 'on_obj', 'px', 'cover', 'spill',
           'spill_on_parts', 'box_iou', 'box_ratio', 'other_share')
MOST = 0.8


def _detail(cause: str, cover: float, box_ratio: float, other_share: float) -> str:
    if cause == 'piece of a found part':
        return 'duplicate'
    if cause != 'piece of a missed part':
        return cause
    if other_share >= 1 / 6:
        return 'split'
    return 'fattened' if cover >= MOST and box_ratio > 1 else 'shrunk'


def box_rows(image, labels: np.ndarray, boxes: list, matched: dict[int, int],
             causes: list[str]) -> list[tuple]:
    """The rows of one frame's unmatched boxes (``causes``: `evaluate`'s, in box order)."""
    ids = [int(i) for i in np.unique(labels) if i]
    used = set(matched.values())
    gts = [gt.mask if gt.mask is not None else np.zeros(labels.shape, bool) for gt in image.gt]
    any_part = np.any(gts, axis=0) if gts else np.zeros(labels.shape, bool)
    rows = []
    unmatched = [j for j in range(len(ids)) if j not in used]
    for j, cause in zip(unmatched, causes):
        mask = labels == ids[j]
        on = [int((mask & m).sum()) for m in gts]
        k = int(np.argmax(on)) if on and max(on) else -1
        px = int(mask.sum())
        if k < 0:
            rows.append((image.im_id, cause, cause, boxes[j][4], 0, px, 0.0, 1.0,
                         0.0, 0.0, 0.0, 0.0))
            continue
        part = gts[k]
        off = mask & ~part
        gt_box = image.gt[k].bbox_visib
        box = boxes[j][:4]
        shares = [int((labels[part] == i).sum()) / max(1, int(part.sum()))
                  for i in ids if i != ids[j]]
        other = max(shares, default=0.0)
        cover = on[k] / max(1, int(part.sum()))
        ratio = box[2] * box[3] / max(1, gt_box[2] * gt_box[3])
        rows.append((image.im_id, cause, _detail(cause, cover, ratio, other), boxes[j][4],
                     image.gt[k].obj_id, px, cover, int(off.sum()) / px,
                     int((off & any_part).sum()) / max(1, int(off.sum())),
                     box_iou(gt_box, box), ratio, other))
    return rows


def evaluate_seeing_frames(rest: list[str], on_frame) -> int:
    """``tlessbot evaluate REST``, calling ``on_frame(image, labels, boxes, matched)`` with each
    frame's scoring inputs (``eval_scoring.frame_breakdown``'s, which it does not change).
    Returns evaluate's exit code."""
    original = eval_scoring.frame_breakdown

    def spy(image, labels, boxes, matched, **kw):
        on_frame(image, labels, boxes, matched)
        return original(image, labels, boxes, matched, **kw)
    eval_scoring.frame_breakdown = spy
    from tlessbot_ros.tools.cli import main as cli_main
    try:
        return cli_main(['evaluate', *rest])
    finally:
        eval_scoring.frame_breakdown = original


def main(argv: list[str]) -> int:
    path, rest = argv[0], argv[argv.index('--') + 1:]
    rows: list[tuple] = []
    labels_by_frame: dict[str, np.ndarray] = {}

    def seen(image, labels, boxes, matched):
        labels_by_frame[f'frame{image.im_id}'] = labels
        order = _fp_order(image, labels, boxes, matched)
        rows.extend(box_rows(image, labels, boxes, matched, order))
    code = evaluate_seeing_frames(rest, seen)
    np.savez_compressed(path.rsplit('.', 1)[0] + '_labels.npz', **labels_by_frame)
    with open(path, 'w') as out:
        out.write('\t'.join(COLUMNS) + '\n')
        for row in rows:
            out.write('\t'.join(f'{v:.3f}' if isinstance(v, float) else str(v)
                                for v in row) + '\n')
    return int(code or 0)


def _fp_order(image, labels, boxes, matched) -> list[str]:
    """`evaluate`'s cause of each unmatched box, in box order: ``frame_breakdown`` on the
    frame with that box as the only unmatched one (a box's cause depends on it alone)."""
    causes = []
    used = set(matched.values())
    ids = [int(i) for i in np.unique(labels) if i]
    for j in range(len(ids)):
        if j in used:
            continue
        keep = labels.copy()
        for other in range(len(ids)):
            if other != j and other not in used:
                keep[keep == ids[other]] = 0
        sub_boxes = [b for n, b in enumerate(boxes) if n == j or n in used]
        remap = {old: new for new, old in enumerate(n for n in range(len(ids))
                                                     if n == j or n in used)}
        sub_matched = {k: remap[v] for k, v in matched.items()}
        counts = _original_breakdown(image, keep, sub_boxes, sub_matched)['false_pos']
        causes.append(next((c for c, n in counts.items() if n), 'none'))
    return causes


def _original_breakdown(image, labels, boxes, matched):
    from tlessbot_ros.tools.support.eval_breakdown import frame_breakdown
    return frame_breakdown(image, labels, boxes, matched)


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
