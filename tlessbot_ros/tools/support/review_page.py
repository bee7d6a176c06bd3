"""The Markdown page ``tlessbot approve`` writes beside the expected poses: per frame, the side
view's overlay (PNG: depth in false colour, part outlines, posed model points) and the parts
with their poses and scores, for a person to look at before committing the file."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import rpy_from_matrix
from tlessbot_ros.core.regression import PartPose


def part_row(part: PartPose) -> str:
    """``| obj_05 | frame | x, y, z mm | roll, pitch, yaw deg | 0.93 |``"""
    x, y, z = 1e3 * part.T[:3, 3]
    roll, pitch, yaw = np.degrees(rpy_from_matrix(part.T[:3, :3]))
    score = '' if part.score is None else f'{part.score:.2f}'
    return (f'| {part.name} | `{part.frame_id}` | {x:+.1f}, {y:+.1f}, {z:+.1f} | '
            f'{roll:+.1f}, {pitch:+.1f}, {yaw:+.1f} | {score} |')


def write_review_page(page: Path, frames: Mapping[int, Sequence[PartPose]],
                      overlays: Mapping[int, np.ndarray], *, title: str, notes: Sequence[str]
                      ) -> int:
    """Write ``page`` and its PNGs into ``<page stem>_overlays/``; returns the PNGs written."""
    import cv2

    folder = page.with_name(page.stem + '_overlays')
    folder.mkdir(parents=True, exist_ok=True)
    lines = [f'# {title}', '', *notes, '']
    written = 0
    for index, stamp in enumerate(sorted(frames)):
        parts = sorted(frames[stamp], key=lambda p: p.name)
        lines += [f'## Frame {index} (stamp {stamp / 1e9:.3f} s, {len(parts)} parts)', '']
        image = overlays.get(stamp)
        if image is not None:
            name = f'frame_{index:03d}.png'
            cv2.imwrite(str(folder / name), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
            written += 1
            lines += [f'![frame {index}]({folder.name}/{name})', '']
        else:
            lines += ['(no overlay received for this frame)', '']
        if parts:
            lines += ['| part | frame | position (mm) | roll, pitch, yaw (deg) | score |',
                      '|---|---|---|---|---|', *(part_row(p) for p in parts), '']
    page.write_text('\n'.join(lines), encoding='utf-8')
    return written
