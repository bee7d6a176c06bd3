"""BOP results files: ``scene_id,im_id,obj_id,score,R,t,time`` (one pose per line).

Format (bop_toolkit ``docs/bop_challenge_2019.md``): ``R`` is the row-major 3x3 rotation as 9
space-separated numbers, ``t`` the translation in **mm** as 3 space-separated numbers, ``time``
the run time per image in seconds (-1 if unknown), all for the pose ``T_camera_object``.
In memory translations are metres.
"""
from __future__ import annotations

import csv
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import nearest_rotation
from tlessbot_ros.errors import DatasetError

HEADER = ('scene_id', 'im_id', 'obj_id', 'score', 'R', 't', 'time')


@dataclass
class BopEstimate:
    """One row of a BOP results file: an estimated pose of one object in one image.

    Attributes:
        scene_id, im_id, obj_id: BOP identifiers.
        score: confidence (higher is better).
        T_camera_object: (4, 4) float64 pose in metres.
        time_s: run time of the whole image in seconds, -1 when unknown.
    """

    scene_id: int
    im_id: int
    obj_id: int
    score: float
    T_camera_object: np.ndarray
    time_s: float = -1.0


def _numbers(text: str, count: int, what: str, where: str) -> np.ndarray:
    try:
        values = np.array([float(v) for v in text.split()])
    except ValueError:
        raise DatasetError(f'{where}: {what} must be {count} numbers, got {text!r}') from None
    if values.size != count or not np.all(np.isfinite(values)):
        raise DatasetError(f'{where}: {what} must be {count} finite numbers, got {text!r}')
    return values


def read_results(path: str | Path) -> list[BopEstimate]:
    """Read a BOP results CSV (a header line is optional).

    Raises:
        DatasetError: the file is missing or a row is malformed (names the line).
    """
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except OSError as error:
        raise DatasetError(f'cannot read results file {path}: {error.strerror}') from None
    results = []
    for number, row in enumerate(csv.reader(text.splitlines()), start=1):
        if not row or all(not cell.strip() for cell in row):
            continue
        where = f'{path}:{number}'
        if number == 1 and row[0].strip() == 'scene_id':
            continue
        if len(row) != 7:
            raise DatasetError(f'{where}: expected 7 fields ({",".join(HEADER)}), got {len(row)}')
        try:
            scene_id, im_id, obj_id = (int(row[i]) for i in range(3))
            score, time_s = float(row[3]), float(row[6])
        except ValueError:
            raise DatasetError(f'{where}: scene_id, im_id, obj_id must be integers and score, '
                               'time numbers') from None
        R = nearest_rotation(_numbers(row[4], 9, 'R', where).reshape(3, 3))
        if R is None:  # near-rotations (BOP's own GT files) are projected onto SO(3)
            raise DatasetError(f'{where}: R is not a rotation matrix (|R R^T - I| or '
                               '|det R - 1| above 0.05, or a reflection)')
        t_mm = _numbers(row[5], 3, 't', where)
        T = np.eye(4)
        T[:3, :3] = R
        T[:3, 3] = t_mm / 1000.0
        results.append(BopEstimate(scene_id, im_id, obj_id, score, T, time_s))
    return results


def write_results(path: str | Path, results: Iterable[BopEstimate]) -> None:
    """Write a BOP results CSV with a header line (t in mm, R row-major)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open('w', encoding='utf-8', newline='') as stream:
        writer = csv.writer(stream, lineterminator='\n')
        writer.writerow(HEADER)
        for r in results:
            T = np.asarray(r.T_camera_object, dtype=np.float64)
            writer.writerow([
                int(r.scene_id), int(r.im_id), int(r.obj_id), f'{float(r.score):.6g}',
                ' '.join(f'{v:.9g}' for v in T[:3, :3].ravel()),
                ' '.join(f'{v:.6f}' for v in T[:3, 3] * 1000.0),
                f'{float(r.time_s):.6g}'])
