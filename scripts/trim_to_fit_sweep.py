"""Boxes and false boxes of one ``tlessbot evaluate`` run with the regions trimmed to their fits
(``FitParams.trim_to_fit_px``, ``core/region_trim.py``) at several settings, from one run.
docs/bench/smoothed-false-parts-now.md (2026-12-06, seventh session).

    python scripts/trim_to_fit_sweep.py TSV [--margins 2,3,4] [--seen 0.5,0.8] -- EVALUATE ARGS...

Runs ``tlessbot evaluate`` with the trim off (main's boxes, its own figures) and, after each
frame's pose stage, trims a copy of the labels at each setting; the trim moves no pose, so
each setting's boxes are scored against the frame's ground truth as ``evaluate`` scores
them (IoU >= 0.7, greedy).
Writes one row per setting to TSV: margin_px, min_seen ('off' for the run's own boxes),
frames, false boxes, false boxes a frame, detected and named right (top-1) over the targets,
the false boxes by ``false_box_causes.py``'s causes, and the trim's process CPU ms a frame.
"""
from __future__ import annotations

import argparse
import copy
import sys
import time
from collections import Counter

import numpy as np

from tlessbot_ros.core.common import mask_box
from tlessbot_ros.tools.support import eval_scoring

sys.path.insert(0, __file__.rsplit('/', 1)[0])
from false_box_causes import _fp_order, box_rows, evaluate_seeing_frames  # noqa: E402

DETAILS = ('fattened', 'shrunk', 'split', 'duplicate', 'merged', 'table, flat', 'table, raised',
           'barely visible part')


def main(argv: list[str]) -> int:
    rest = argv[argv.index('--') + 1:]
    parser = argparse.ArgumentParser()
    parser.add_argument('tsv')
    parser.add_argument('--margins', default='2,3,4,6')
    parser.add_argument('--seen', default='0.5,0.8')
    args = parser.parse_args(argv[:argv.index('--')])
    settings = [(int(m), float(s)) for m in args.margins.split(',')
                for s in args.seen.split(',')]
    import tlessbot_ros.core.colour_rim as after_fits_module
    from tlessbot_ros.core.region_trim import trim_to_fits

    trimmed: dict[int, tuple[np.ndarray, dict]] = {}   # id(side labels): (them, {setting: ..})
    cpu_ms: dict[tuple[int, float], float] = {}   # each setting's trims, process CPU ms

    def spy_trim(pipeline, views, labels, detections, **kw):   # the run itself: trim off
        if 'side' not in labels or kw.get('box_mode'):
            return detections
        by_setting = {}
        for margin, seen in settings:
            copies, boxes = dict(labels), [copy.copy(d) for d in detections]
            t0 = time.process_time()
            trim_to_fits(pipeline, views, copies, boxes, margin_px=margin, min_seen=seen)
            cpu_ms[(margin, seen)] = cpu_ms.get((margin, seen), 0.0) + \
                1e3 * (time.process_time() - t0)
            by_setting[(margin, seen)] = copies['side']
        trimmed[id(labels['side'])] = (labels['side'], by_setting)
        return detections
    after_fits_module.trim_to_fits = spy_trim   # the pipeline's trims after the fits

    totals: dict[object, Counter] = {}

    def seen(image, labels, boxes, matched):
        variants = {'off': labels}
        classes = {int(i): b[4] for i, b in zip((i for i in np.unique(labels) if i), boxes)}
        if id(labels) in trimmed:
            variants.update(trimmed[id(labels)][1])
        for key, lab in variants.items():
            add(totals.setdefault(key, Counter()), image, lab, classes)
    code = evaluate_seeing_frames(rest, seen)
    with open(args.tsv, 'w') as out:
        out.write('\t'.join(('margin_px', 'min_seen', 'frames', 'false', 'fp_frame', 'detected',
                             'top1', *DETAILS, 'trim_cpu_ms_frame')) + '\n')
        for key, c in totals.items():
            margin, seen = ('off', 'off') if key == 'off' else key
            n, t = max(1, c['frames']), max(1, c['targets'])
            out.write('\t'.join(str(v) for v in (
                margin, seen, c['frames'], c['false'], f"{c['false'] / n:.2f}",
                f"{c['detected'] / t:.3f}", f"{c['top1'] / t:.3f}",
                *(c[d] for d in DETAILS),
                f'{cpu_ms.get(key, 0.0) / n:.1f}' if key != 'off' else '')) + '\n')
    return int(code or 0)


def add(counts: Counter, image, labels: np.ndarray, classes: dict[int, int]) -> None:
    """One frame's boxes of ``labels`` ({instance: class}) scored."""
    ids = [int(i) for i in np.unique(labels) if i]
    boxes = [(*mask_box(labels == i), classes[i]) for i in ids]
    matched, false = eval_scoring._match_boxes(image, boxes)
    counts['frames'] += 1
    counts['false'] += false
    for k, gt in enumerate(image.gt):
        if gt.visib_fract is None or gt.visib_fract < eval_scoring.MIN_VISIB_FRACT:
            continue
        counts['targets'] += 1
        if k in matched:
            counts['detected'] += 1
            counts['top1'] += boxes[matched[k]][4] == gt.obj_id
    rows = box_rows(image, labels, boxes, matched, _fp_order(image, labels, boxes, matched))
    counts.update(row[2] for row in rows)


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
