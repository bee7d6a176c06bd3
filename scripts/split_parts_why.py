"""Why a part is reported as several boxes: each split part of a ``tlessbot evaluate`` run, its
pieces and what the joining rules saw. docs/bench/smoothed-split-parts.md.

    python scripts/split_parts_why.py TSV -- EVALUATE ARGUMENTS...
    python scripts/split_parts_why.py --summary TSV [TSV...]   # rows per cause, per file

(also writes ``false_box_causes.py``'s table of every false box to TSV's name with
``_causes.tsv``, and the scored view's labels to ``_labels.npz``, from the same run.)

Runs ``tlessbot evaluate`` (in this process, no pose workers) and writes one row per part of
the scored view that two or more instances each hold at least a sixth of: the part's pixels,
per piece (largest first) its pixels, the share of the part it holds, the share of its own
pixels off the part and whether it is matched, whether the two largest pieces touch (8-
neighbours) and the gap between them (px), and from the pose stage's fragment filter: whether
the two were neighbours there (or which was divided off a fitted region after the fit,
``two_parts.split_off``), their fitted centres' distance over the smaller fitted
diameter, and whether each one's fit explains the other's points (with that fit's share of
the other's points near its surface and inside its outline, ``one_part.explainer``).
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core import one_part, pipeline, two_parts
from tlessbot_ros.core.part_fit import outline_shares

COLUMNS = ('frame', 'obj', 'part_px', 'pieces', 'matched', 'touch', 'gap_px', 'neighbours',
           'centre_d', 'explains_ab', 'explains_ba', 'named')
SIXTH = 1 / 6
sys.path.insert(0, str(Path(__file__).resolve().parent))
import false_box_causes  # noqa: E402  (a script beside this one)


class _Trace:
    """What the pose stage decided per frame: (scored-view labels after the join, records)."""

    def __init__(self) -> None:
        self.frames: list[tuple[dict, dict]] = []
        self.current: dict = {}

    def explainer(self, params, estimator, jobs):
        explains = _original_explainer(params, estimator, jobs)
        if explains is None:
            return None
        by_detection = {id(job.detection): job for job in jobs}
        record = self.current.setdefault('explains', {})

        def traced(a, b) -> bool:
            out = explains(a, b)
            key = (a.instance_id, b.instance_id)
            if key not in record:
                job_a, job_b = by_detection[id(a)], by_detection[id(b)]
                points = one_part.points_in_view(job_b, job_a)
                shares = (0.0, 0.0)
                if points is not None and len(points) and a.pose is not None:
                    shares = outline_shares(params, points, a.obj_id, a.pose, estimator)
                record[key] = (bool(out), float(shares[0]), float(shares[1]))
            return out
        return traced

    def split_off(self, *args, **kwargs):
        piece = _original_split_off(*args, **kwargs)
        if piece is not None:
            self.current.setdefault('divided', set()).add(piece.detection.instance_id)
        return piece

    def join(self, arbiter, detections, labels):
        pieces = {}
        for p in arbiter._pieces:
            pieces[p.detection.instance_id] = dict(
                neighbours=[arbiter._pieces[b].detection.instance_id for b in p.neighbours],
                centre=p.centre, diameter=p.fitted_diameter_m, score=p.score)
        self.current['pieces'] = pieces
        out = _original_join(arbiter, detections, labels)
        self.frames.append((dict(labels), self.current))
        self.current = {}
        return out

    def record_for(self, labels: np.ndarray) -> dict:
        for views, record in self.frames:
            if any(v.shape == labels.shape and np.array_equal(v, labels) for v in views.values()):
                return record
        return {}


_original_explainer = one_part.explainer
_original_join = pipeline.join_pieces
_original_split_off = two_parts.split_off


def _gap_px(a: np.ndarray, b: np.ndarray) -> float:
    """The shortest distance (px) from a pixel of ``a`` to one of ``b``."""
    far = cv2.distanceTransform(np.where(b, 0, 1).astype(np.uint8), cv2.DIST_L2, 3)
    return float(far[a].min()) if a.any() else -1.0


def _shown(explained: tuple[bool, float, float] | None) -> str:
    return '-' if explained is None else \
        f'{int(explained[0])}({explained[1]:.2f},{explained[2]:.2f})'


def split_rows(image, labels: np.ndarray, boxes: list, matched: dict[int, int],
               record: dict) -> list[tuple]:
    ids = [int(i) for i in np.unique(labels) if i]
    used = set(matched.values())
    rows = []
    for gt in image.gt:
        if gt.mask is None or not gt.mask.any():
            continue
        part = gt.mask
        n = int(part.sum())
        held = [(int((labels[part] == i).sum()), j, i) for j, i in enumerate(ids)]
        pieces = sorted([h for h in held if h[0] >= SIXTH * n], reverse=True)
        if len(pieces) < 2:
            continue
        text = []
        for on, j, i in pieces:
            mask = labels == i
            text.append(f'{i}:{int(mask.sum())}px/{on / n:.2f}/off{1 - on / mask.sum():.2f}'
                        f'{"/M" if j in used else ""}')
        a, b = (labels == pieces[0][2]), (labels == pieces[1][2])
        touch = bool((cv2.dilate(a.view(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
                      & b).any())
        ia, ib = pieces[0][2], pieces[1][2]
        info = record.get('pieces', {})
        pa, pb = info.get(ia), info.get(ib)
        neighbours = 'n/a' if pa is None or pb is None else str(ib in pa['neighbours'])
        divided = [i for i in (ia, ib) if i in record.get('divided', ())]
        if divided:   # divided off its region after the fit (two_parts.split_off)
            neighbours = 'divided ' + ','.join(map(str, divided))
        centre_d = 'n/a'
        if pa and pb and pa['centre'] is not None and pb['centre'] is not None:
            d = float(np.linalg.norm(pa['centre'] - pb['centre']))
            centre_d = f'{d / max(1e-9, min(pa["diameter"], pb["diameter"])):.2f}'
        ex = record.get('explains', {})
        rows.append((image.im_id, gt.obj_id, n, ' '.join(text),
                     int(any(j in used for _, j, _ in pieces)), int(touch),
                     f'{_gap_px(a, b):.1f}', neighbours, centre_d, _shown(ex.get((ia, ib))),
                     _shown(ex.get((ib, ia))), ','.join(str(boxes[j][4]) for _, j, _ in pieces)))
    return rows


def cause(row: dict[str, str]) -> str:
    """A split part's cause (docs/bench/smoothed-split-parts.md): a piece mostly on another
    part (``mixed``), a piece divided off after the fit (``divided``), a piece with no fit in
    the fragment filter (``unfitted``), else two fits neither explaining the other, their
    regions touching (``touching``, within 3 px) or not (``apart``)."""
    offs = [float(p.split('/off')[1].split('/')[0]) for p in row['pieces'].split()]
    if max(offs[:2]) >= 0.5:
        return 'mixed'
    if row['neighbours'].startswith('divided'):
        return 'divided'
    if row['explains_ab'] == '-' or row['neighbours'] == 'n/a':
        return 'unfitted'
    return 'touching' if float(row['gap_px']) <= 4.0 else 'apart'


def summary(paths: list[str]) -> None:
    names = ('mixed', 'divided', 'unfitted', 'touching', 'apart')
    print('file\t' + '\t'.join(names))
    for path in paths:
        with open(path) as rows:
            head = rows.readline().rstrip('\n').split('\t')
            found = [cause(dict(zip(head, line.rstrip('\n').split('\t')))) for line in rows]
        print(path + '\t' + '\t'.join(str(found.count(n)) for n in names))


def main(argv: list[str]) -> int:
    if argv[0] == '--summary':
        summary(argv[1:])
        return 0
    path, rest = argv[0], argv[argv.index('--') + 1:]
    trace = _Trace()
    one_part.explainer = trace.explainer
    pipeline.join_pieces = trace.join
    two_parts.split_off = trace.split_off
    rows: list[tuple] = []
    causes: list[tuple] = []
    labels_by_frame: dict[str, np.ndarray] = {}

    def seen(image, labels, boxes, matched):
        labels_by_frame[f'frame{image.im_id}'] = labels
        rows.extend(split_rows(image, labels, boxes, matched, trace.record_for(labels)))
        order = false_box_causes._fp_order(image, labels, boxes, matched)
        causes.extend(false_box_causes.box_rows(image, labels, boxes, matched, order))
    code = false_box_causes.evaluate_seeing_frames(rest, seen)
    _write(path, COLUMNS, rows)
    np.savez_compressed(path.rsplit('.', 1)[0] + '_labels.npz', **labels_by_frame)
    _write(path.rsplit('.', 1)[0] + '_causes.tsv', false_box_causes.COLUMNS, causes)
    return int(code or 0)


def _write(path: str, columns: tuple[str, ...], rows: list[tuple]) -> None:
    with open(path, 'w') as out:
        out.write('\t'.join(columns) + '\n')
        for row in rows:
            out.write('\t'.join(f'{v:.3f}' if isinstance(v, float) else str(v)
                                for v in row) + '\n')


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
