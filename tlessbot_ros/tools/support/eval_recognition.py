"""The recognition page of ``tlessbot evaluate --oracle boxes``: per-part top-1 of the classifier
alone and after the pose stage, the confusion table, and a sheet of the worst crops.

The worst crops are the wrong answers the classifier was surest of (largest margin): each tile
is the ground-truth box of the part, captioned with the part it was taken for and the part it
is. Written as ``recognition.md`` and ``worst_crops.png`` beside ``report.md``.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common.names import part_name
from tlessbot_ros.tools.support.report import cell as _cell

MIN_VISIB_FRACT = 0.3  # the scored targets, as in eval_scoring
_TILE_PX = 96
_CAPTION_PX = 28


@dataclass(frozen=True)
class CropAnswer:
    """One scored ground-truth part: where it is and what the classifier said."""

    frame: int
    gt_index: int
    truth: int
    classifier: int
    margin: float
    final: int     # the class after the pose stage's verification (= classifier without it)
    posed: bool    # the pose stage ran on this frame (it has depth)


def crop_answers(frames: list) -> list[CropAnswer]:
    """Every target (visib_fract >= 0.3) of frames that carry ``classifier_by_gt``."""
    answers = []
    for index, (image, output) in enumerate(frames):
        if output.classifier_by_gt is None:
            continue
        for k, gt in enumerate(image.gt):
            if gt.visib_fract is None or gt.visib_fract < MIN_VISIB_FRACT:
                continue
            guess, margin = output.classifier_by_gt.get(k, (0, 0.0))
            final = (output.classes_by_gt or {}).get(k, guess)
            answers.append(CropAnswer(index, k, int(gt.obj_id), int(guess), float(margin),
                                      int(final), bool(output.pose_ran)))
    return answers


def _share(hits: np.ndarray) -> float | None:
    return float(np.mean(hits)) if hits.size else None


def summary(answers: list[CropAnswer]) -> dict:
    """JSON-ready: top-1 of the classifier alone over every crop, and on the crops of frames
    the pose stage ran on (with depth) the classifier alone and after the pose stage, overall
    and per part; the confusion matrix (rows truth, columns answer, id 0 = unknown) and its
    ids."""
    truths = np.array([a.truth for a in answers], np.int64)
    alone = np.array([a.classifier for a in answers], np.int64)
    final = np.array([a.final for a in answers], np.int64)
    posed = np.array([a.posed for a in answers], bool)
    ids = sorted(set(truths.tolist()) | set(alone.tolist()) | {0})
    matrix = np.zeros((len(ids), len(ids)), np.int64)
    for t, c in zip(truths, alone):
        matrix[ids.index(t), ids.index(c)] += 1
    per_part = {str(i): {'crops': int((truths == i).sum()),
                         'top1_classifier': _share(alone[truths == i] == i),
                         'posed_crops': int((posed & (truths == i)).sum()),
                         'top1_after_pose': _share(final[posed & (truths == i)] == i)}
                for i in sorted(set(truths.tolist()))}
    return {'crops': len(answers),
            'top1_classifier': _share(alone == truths),
            'posed_crops': int(posed.sum()),
            'top1_classifier_posed': _share(alone[posed] == truths[posed]),
            'top1_after_pose': _share(final[posed] == truths[posed]),
            'unknown_rate': _share(alone == 0),
            'per_part': per_part, 'confusion_ids': ids, 'confusion': matrix.tolist()}


def markdown(result: dict, names: Mapping[int, str] | None = None) -> str:
    """``recognition.md``: per-part table and confusion table (classifier alone); parts named
    by ``names`` ({id: name}; obj_NN when not listed)."""
    lines = ['# Recognition on ground-truth boxes', '',
             f'- crops (visib_fract >= {MIN_VISIB_FRACT}): {result["crops"]}',
             f'- top-1, classifier alone: {_cell(result["top1_classifier"])}',
             f'- on the {result["posed_crops"]} crops of frames with depth: classifier alone '
             f'{_cell(result["top1_classifier_posed"])}, after the pose stage '
             f'{_cell(result["top1_after_pose"])}',
             f'- called unknown: {_cell(result["unknown_rate"])}', '',
             '| part | crops | classifier alone | crops with depth | after pose stage |',
             '|---|---|---|---|---|']
    for key, row in result['per_part'].items():
        lines.append(f'| {name(int(key), names)} | {row["crops"]} | '
                     f'{_cell(row["top1_classifier"])} | {row["posed_crops"]} | '
                     f'{_cell(row["top1_after_pose"])} |')
    ids = result['confusion_ids']
    lines += ['', '## Confusion, classifier alone (rows: the part, columns: taken for)', '',
              '| part | ' + ' | '.join(name(i, names) for i in ids) + ' |',
              '|---' * (len(ids) + 1) + '|']
    for i, row in zip(ids, result['confusion']):
        if sum(row):
            lines.append(f'| {name(i, names)} | ' + ' | '.join(str(v) for v in row) + ' |')
    lines += ['', '![worst crops](worst_crops.png)', '',
              'The wrong answers the classifier was surest of: the crop, the part it was taken '
              'for, the part it is.']
    return '\n'.join(lines) + '\n'


def worst_crops_sheet(frames: list, answers: list[CropAnswer], *, count: int = 24,
                      columns: int = 8, names: Mapping[int, str] | None = None
                      ) -> np.ndarray | None:
    """(H, W, 3) uint8 RGB sheet of the ``count`` surest wrong answers; None if none."""
    import cv2

    wrong = sorted((a for a in answers if a.classifier != a.truth), key=lambda a: -a.margin)
    wrong = wrong[:count]
    if not wrong:
        return None
    rows = (len(wrong) + columns - 1) // columns
    sheet = np.full((rows * (_TILE_PX + _CAPTION_PX), columns * _TILE_PX, 3), 255, np.uint8)
    for n, answer in enumerate(wrong):
        image = frames[answer.frame][0]
        x, y, w, h = image.gt[answer.gt_index].bbox_visib
        crop = np.asarray(image.rgb)[max(y, 0):y + h, max(x, 0):x + w]
        side = max(crop.shape[:2])
        square = np.zeros((side, side, 3), np.uint8)
        square[:crop.shape[0], :crop.shape[1]] = crop
        top, left = (n // columns) * (_TILE_PX + _CAPTION_PX), (n % columns) * _TILE_PX
        sheet[top:top + _TILE_PX, left:left + _TILE_PX] = cv2.resize(square,
                                                                   (_TILE_PX, _TILE_PX))
        for line, text in enumerate((f'took {name(answer.classifier, names)}',
                                     f'is {name(answer.truth, names)}')):
            cv2.putText(sheet, text, (left + 2, top + _TILE_PX + 11 + 13 * line),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
    return sheet


def name(obj_id: int, names: Mapping[int, str] | None = None) -> str:
    """A part's name in reports (``names[obj_id]``, else ``obj_NN``; id 0 is unknown)."""
    return 'unknown' if obj_id == 0 else part_name(obj_id, names)


def write_recognition_page(frames: list, out: Path, names: Mapping[int, str] | None = None
                           ) -> dict | None:
    """Write ``recognition.md`` and ``worst_crops.png`` into ``out`` (parts named by
    ``names``); the summary, or None when no frame carries classifier answers on ground-truth
    boxes."""
    import cv2

    answers = crop_answers(frames)
    if not answers:
        return None
    result = summary(answers)
    out.mkdir(parents=True, exist_ok=True)
    (out / 'recognition.md').write_text(markdown(result, names), encoding='utf-8')
    sheet = worst_crops_sheet(frames, answers, names=names)
    if sheet is not None:
        cv2.imwrite(str(out / 'worst_crops.png'), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
    return result
