"""Where the detections of ``tlessbot evaluate`` go wrong: each miss and each false positive
of the scored (side) view put in one cause, from the localiser's instance masks against the
ground-truth visible masks.

A part (visib_fract >= 0.3) that no box matches at IoU >= 0.7 is

* ``not found``: no instance holds a fifth of its visible pixels;
* ``merged``: the instance that holds most of it holds a third of another part too;
* ``split``: two or more instances each hold a sixth of it;
* ``box off``: one instance holds it, but its box is too large or too small.

A box that matches no part is

* ``merged``: it holds a third of two or more parts' visible pixels;
* ``piece of a found part``: most of it lies on a part that another box matches (a half of a
  thin part, a fragment, the same part twice);
* ``piece of a missed part``: most of it lies on a target part that no box matches;
* ``barely visible part``: most of it lies on a part less than 30 % visible (not a target);
* ``table``: most of it lies on no part; its median height above the table says
  ``table, flat`` (shadows, table texture, under 3 mm) or ``table, raised`` (a table edge or
  the depth's noise at a part's border);

each also counted as ``with a pose`` when the pipeline published a pose for it.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from tlessbot_ros.core.common.names import part_name

MISS_CAUSES = ('not found', 'merged', 'split', 'box off')
FP_CAUSES = ('merged', 'piece of a found part', 'piece of a missed part',
             'barely visible part', 'table, flat', 'table, raised')
_FLAT_M = 0.003


def _heights(image, mask: np.ndarray) -> float | None:
    """Median height above the table (m) of a mask's pixels with depth, or None."""
    if image.depth_m is None or image.T_world_camera is None:
        return None
    ys, xs = np.nonzero(mask)
    z = image.depth_m[ys, xs]
    ok = np.isfinite(z) & (z > 0)
    if not ok.any():
        return None
    K = image.intrinsics.K
    cam = np.column_stack([(xs[ok] - K[0, 2]) * z[ok] / K[0, 0],
                           (ys[ok] - K[1, 2]) * z[ok] / K[1, 1], z[ok]])
    T = image.T_world_camera
    return float(np.median(cam @ T[2, :3] + T[2, 3]))


def frame_breakdown(image, labels: np.ndarray, boxes: list, matched: dict[int, int],
                    *, min_visib: float = 0.3) -> dict:
    """The causes of one frame's misses and false positives.

    Args:
        image: the scored BOP image (its ground truth with visible masks, depth, extrinsics).
        labels: (H, W) instance labels of the scored view (0 = background).
        boxes: (x, y, w, h, obj_id) per instance, in the order of ``np.unique(labels)[1:]``.
        matched: {ground-truth index: box index} of the IoU >= 0.7 matching.

    Returns:
        {'missed': {cause: n}, 'false_pos': {cause: n}, 'false_pos_posed': {cause: n},
        'missed_by_obj': {obj_id: {cause: n}}}.
    """
    out = {'missed': dict.fromkeys(MISS_CAUSES, 0), 'false_pos': dict.fromkeys(FP_CAUSES, 0),
           'false_pos_posed': dict.fromkeys(FP_CAUSES, 0), 'missed_by_obj': {}}
    gts = [(k, gt) for k, gt in enumerate(image.gt) if gt.mask is not None]
    ids = [int(i) for i in np.unique(labels) if i]
    if len(ids) != len(boxes):
        return out
    n_gt = len(image.gt)
    # overlap[j, k]: pixels of instance j on part k's visible mask
    overlap = np.zeros((len(ids), n_gt), np.int64)
    gt_px = np.zeros(n_gt, np.int64)
    index = np.zeros(int(labels.max()) + 1, np.int64)
    index[ids] = np.arange(len(ids))
    for k, gt in gts:
        gt_px[k] = np.count_nonzero(gt.mask)
        counts = np.bincount(index[labels[gt.mask]], weights=(labels[gt.mask] > 0),
                             minlength=len(ids))
        overlap[:, k] = counts.astype(np.int64)
    inst_px = np.bincount(index[labels[labels > 0]], minlength=len(ids))
    is_target = np.array([(gt.visib_fract or 0.0) >= min_visib for gt in image.gt], bool)
    holds = overlap >= np.maximum(1, gt_px / 3)[None, :]     # instance holds a third of part
    for k, gt in gts:
        if not is_target[k] or k in matched or gt_px[k] == 0:
            continue
        share = overlap[:, k] / gt_px[k]
        if share.max(initial=0) < 0.2:
            cause = 'not found'
        else:
            j = int(np.argmax(share))
            if np.count_nonzero(holds[j]) >= 2:
                cause = 'merged'
            elif np.count_nonzero(share >= 1 / 6) >= 2:
                cause = 'split'
            else:
                cause = 'box off'
        out['missed'][cause] += 1
        per = out['missed_by_obj'].setdefault(int(gt.obj_id), dict.fromkeys(MISS_CAUSES, 0))
        per[cause] += 1
    used = set(matched.values())
    for j in range(len(ids)):
        if j in used:
            continue
        if np.count_nonzero(holds[j]) >= 2:
            cause = 'merged'
        elif overlap[j].sum() * 2 >= inst_px[j]:
            k = int(np.argmax(overlap[j]))
            cause = ('barely visible part' if not is_target[k] else
                     'piece of a found part' if k in matched else 'piece of a missed part')
        else:
            height = _heights(image, labels == ids[j])
            cause = 'table, flat' if height is None or height < _FLAT_M else 'table, raised'
        out['false_pos'][cause] += 1
        if boxes[j][4]:
            out['false_pos_posed'][cause] += 1
    return out


def add_up(parts: list[dict]) -> dict:
    """The sum of :func:`frame_breakdown` results."""
    total = {'missed': dict.fromkeys(MISS_CAUSES, 0), 'false_pos': dict.fromkeys(FP_CAUSES, 0),
             'false_pos_posed': dict.fromkeys(FP_CAUSES, 0), 'missed_by_obj': {}}
    for part in parts:
        for key in ('missed', 'false_pos', 'false_pos_posed'):
            for cause, n in part[key].items():
                total[key][cause] += n
        for obj, causes in part['missed_by_obj'].items():
            mine = total['missed_by_obj'].setdefault(str(obj), dict.fromkeys(MISS_CAUSES, 0))
            for cause, n in causes.items():
                mine[cause] += n
    return total


def confusions(frames_boxes: list[tuple[object, list, dict[int, int]]]) -> dict[str, int]:
    """{'true -> named': count} of the matched boxes named as another part (0: no pose)."""
    out: dict[str, int] = {}
    for image, boxes, matched in frames_boxes:
        for k, j in matched.items():
            named, truth = int(boxes[j][4]), int(image.gt[k].obj_id)
            if named != truth and (image.gt[k].visib_fract or 0.0) >= 0.3:
                key = f'{truth} -> {named}'
                out[key] = out.get(key, 0) + 1
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def markdown(breakdown: dict, frames: int, names: Mapping[int, str] | None = None
             ) -> list[str]:
    """report.md lines of a breakdown (:func:`add_up` plus 'confusions'); parts named by
    ``names`` ({id: name}; obj_NN when not listed)."""
    lines = ['', '## Detection losses by cause (scored view)', '',
             '| misses (target parts) | ' + ' | '.join(MISS_CAUSES) + ' |',
             '|---' * (len(MISS_CAUSES) + 1) + '|',
             '| all | ' + ' | '.join(str(breakdown['missed'][c]) for c in MISS_CAUSES) + ' |']
    for obj, causes in sorted(breakdown['missed_by_obj'].items(), key=lambda kv: int(kv[0])):
        lines.append(f'| {part_name(int(obj), names)} | '
                     + ' | '.join(str(causes[c]) for c in MISS_CAUSES) + ' |')
    lines += ['', '| false positives | ' + ' | '.join(FP_CAUSES) + ' | per frame |',
              '|---' * (len(FP_CAUSES) + 2) + '|']
    for key, name in (('false_pos', 'boxes'), ('false_pos_posed', 'with a pose')):
        counts = breakdown[key]
        lines.append(f'| {name} | ' + ' | '.join(str(counts[c]) for c in FP_CAUSES)
                     + f' | {sum(counts.values()) / max(frames, 1):.2f} |')
    wrong = [([int(i) for i in k.split(' -> ')], n)
             for k, n in breakdown.get('confusions', {}).items()]
    lines += ['', 'Matched boxes named as another part (true -> named, 0: no pose): '
              + (', '.join(f'{part_name(truth, names)} -> '
                           f'{part_name(named, names) if named else 0} ({n})'
                           for (truth, named), n in wrong) or 'none') + '.']
    return lines
