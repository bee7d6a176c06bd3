"""Two touching parts alike in chroma but not in lightness are divided (blob_split)."""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.localise import SegmentationParams
from tlessbot_ros.core.localise.instances import _instances, split_touching

# one part known: 50 mm, its smallest whole blob 400 px, as long as 200 px; the rule on
PARTS = SegmentationParams(whole_parts=((0.05, 400.0, 200.0),), lightness_split_ratio=8.0)


def _two_halves(left: float, right: float, width: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """A blob 40 px high of two grey halves (each ``width`` wide, no neck between them) on a
    table; the halves' lightness ``left`` / ``right`` (8-bit grey), each face shaded by 10 %
    across its width (as a lit face is)."""
    rng = np.random.default_rng(0)
    rgb = np.full((80, 2 * width + 40, 3), 140.0)
    mask = np.zeros(rgb.shape[:2], bool)
    mask[20:60, 20:20 + 2 * width] = True
    ramp = np.linspace(0.95, 1.05, width)[None, :, None]
    rgb[20:60, 20:20 + width] = left * ramp
    rgb[20:60, 20 + width:20 + 2 * width] = right * ramp
    rgb = np.clip(rgb + rng.normal(0, 1.5, rgb.shape), 0, 255).astype(np.uint8)
    return mask, rgb


def _count(mask: np.ndarray, rgb: np.ndarray, params: SegmentationParams) -> int:
    return int(split_touching(mask, rgb, params=params).max())


def test_a_white_and_a_black_part_touching_are_two() -> None:
    mask, rgb = _two_halves(230, 20)
    assert _count(mask, rgb, PARTS) == 2
    assert _count(mask, rgb, SegmentationParams(whole_parts=PARTS.whole_parts)) == 1   # off
    # the halves are groups of their own, so that the fusion keeps them apart
    labels, _, _, groups = _instances(mask, rgb, PARTS)
    assert labels.max() == 2 and groups.min() > 0 and groups[0] != groups[1]


def test_shading_and_small_pieces_do_not_divide() -> None:
    # one grey part, a face lit and one in shade: lightness three times apart
    mask, rgb = _two_halves(210, 70)
    assert _count(mask, rgb, PARTS) == 1
    # a black piece smaller than any whole part (a part partly hidden, a dark mark)
    mask, rgb = _two_halves(230, 20, width=8)   # 320 px of 400
    assert _count(mask, rgb, PARTS) == 1
    # the parts unknown: no piece can be told a part
    mask, rgb = _two_halves(230, 20)
    assert _count(mask, rgb, SegmentationParams(lightness_split_ratio=8.0)) == 1
