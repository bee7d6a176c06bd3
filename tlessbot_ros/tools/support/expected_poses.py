"""The approved poses of a bag as YAML: ``tlessbot approve`` writes it, check reads it.

    format: tlessbot-expected-poses
    version: 1
    bag: bags/demo
    replay: lockstep
    frames:
    - stamp_ns: 1700000000000000000
      parts:
      - {name: obj_05, frame_id: side_color_optical_frame, position_m: [x, y, z],
         quaternion_xyzw: [x, y, z, w], score: 0.93}

Every replayed frame is listed, also one without parts (a part found there later is a
regression too). Metres, unit quaternions, stamps in integer nanoseconds.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from tlessbot_ros.core.common import make_transform, matrix_from_quaternion, quaternion_from_matrix
from tlessbot_ros.core.regression import PartPose
from tlessbot_ros.errors import TlessbotError

FORMAT = 'tlessbot-expected-poses'
VERSION = 1


class ExpectedFileError(TlessbotError):
    """An expected-poses file is missing or malformed."""


@dataclass
class ApprovedRun:
    """Parts per frame (source stamp, ns) and how the run was made."""

    frames: dict[int, list[PartPose]] = field(default_factory=dict)
    info: dict[str, Any] = field(default_factory=dict)


def _part_entry(part: PartPose) -> dict[str, Any]:
    entry: dict[str, Any] = {
        'name': part.name, 'frame_id': part.frame_id,
        'position_m': [round(float(v), 6) for v in part.T[:3, 3]],
        'quaternion_xyzw': [round(float(v), 7) for v in quaternion_from_matrix(part.T[:3, :3])]}
    if part.score is not None:
        entry['score'] = round(float(part.score), 3)
    return entry


def dump_expected(run: ApprovedRun) -> str:
    """The YAML text of ``run`` (parts of a frame sorted by name, then position)."""
    frames = []
    for stamp in sorted(run.frames):
        parts = sorted(run.frames[stamp], key=lambda p: (p.name, *p.T[:3, 3].round(4)))
        frames.append({'stamp_ns': int(stamp), 'parts': [_part_entry(p) for p in parts]})
    document = {'format': FORMAT, 'version': VERSION, **run.info, 'frames': frames}
    return yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=99)


def write_expected(path: str | Path, run: ApprovedRun) -> None:
    Path(path).write_text(dump_expected(run), encoding='utf-8')


def _read_part(entry: Mapping[str, Any]) -> PartPose:
    position = np.asarray(entry['position_m'], dtype=np.float64)
    quaternion = np.asarray(entry['quaternion_xyzw'], dtype=np.float64)
    if position.shape != (3,) or quaternion.shape != (4,) or not np.any(quaternion):
        raise ValueError('position_m needs 3 numbers and quaternion_xyzw 4, not all zero')
    score = entry.get('score')
    return PartPose(str(entry['name']), make_transform(matrix_from_quaternion(quaternion),
                                                       position),
                    str(entry['frame_id']), None if score is None else float(score))


def read_expected(path: str | Path) -> ApprovedRun:
    """Read a file :func:`write_expected` wrote.

    Raises:
        ExpectedFileError: missing file, not YAML, or not this format (the line says which).
    """
    path = Path(path)
    if not path.is_file():
        raise ExpectedFileError(f'expected-poses file not found: {path} (write it with '
                                'tlessbot approve BAG --out FILE)')
    try:
        document = yaml.safe_load(path.read_text(encoding='utf-8'))
    except yaml.YAMLError as error:
        raise ExpectedFileError(f'{path} is not YAML: {str(error).splitlines()[0]}') from None
    if not isinstance(document, dict) or document.get('format') != FORMAT:
        raise ExpectedFileError(f'{path} is not a {FORMAT} file (write it with tlessbot '
                                'approve)')
    if document.get('version') != VERSION:
        raise ExpectedFileError(f'{path} has version {document.get("version")}; this '
                                f'tlessbot reads version {VERSION}')
    run = ApprovedRun(info={k: v for k, v in document.items()
                            if k not in ('format', 'version', 'frames')})
    try:
        for frame in document.get('frames') or ():
            run.frames[int(frame['stamp_ns'])] = [_read_part(p) for p in frame['parts'] or ()]
    except (KeyError, TypeError, ValueError) as error:
        raise ExpectedFileError(f'{path}: malformed frame or part entry ({error!r})') from None
    return run


def frames_from_parts(stamps: Sequence[int], parts: Sequence[tuple[int, PartPose]]
                      ) -> dict[int, list[PartPose]]:
    """{stamp: parts} with every stamp of ``stamps`` present (empty lists for no part)."""
    frames: dict[int, list[PartPose]] = {int(s): [] for s in stamps}
    for stamp, part in parts:
        frames.setdefault(int(stamp), []).append(part)
    return frames
