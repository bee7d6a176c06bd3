"""Two touching parts alike in chroma but not in lightness are divided (blob_split), and
kept apart by the fusion where the top view shows two lightnesses too."""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.localise import FusionParams, Segmentation, SegmentationParams
from tlessbot_ros.core.localise.calibrated_fusion import _side_pieces_of_blob
from tlessbot_ros.core.localise.instances import LIGHTNESS_GROUPS, _instances, split_touching
from tlessbot_ros.core.localise.lightness import two_lightnesses

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
    assert _count(mask, rgb, SegmentationParams(whole_parts=PARTS.whole_parts,
                                                lightness_split_ratio=0.0)) == 1   # off
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


# ------------------------------------------------------------------ the fusion and the top view
def _side_of_two_halves(groups: tuple[int, int]) -> tuple[np.ndarray, Segmentation]:
    """A side blob of two instances (left / right half) with the depth groups given."""
    labels = np.zeros((40, 60), np.uint16)
    labels[10:30, 10:30], labels[10:30, 30:50] = 1, 2
    seg = Segmentation(labels=labels, boxes=np.array([[10, 10, 20, 20], [30, 10, 20, 20]],
                                                     np.int32),
                       areas=np.array([400, 400], np.int64), foreground=labels > 0,
                       depth_groups=np.array(groups, np.int32), thin=np.zeros(2, bool))
    return labels > 0, seg


def test_lightness_halves_stay_apart_where_the_top_showstwo_lightnesses() -> None:
    blob, side = _side_of_two_halves((LIGHTNESS_GROUPS, LIGHTNESS_GROUPS + 1))
    params = FusionParams()
    apart = _side_pieces_of_blob(blob, side.labels, side, params, lit_apart=lambda: True)
    assert len(apart) == 2
    # the top view sees one lightness (a grey part's face dark from the side only): one part
    assert _side_pieces_of_blob(blob, side.labels, side, params, lit_apart=lambda: False) == []
    # a depth split is kept whatever the top's lightness
    blob, side = _side_of_two_halves((1, 2))
    assert len(_side_pieces_of_blob(blob, side.labels, side, params,
                                    lit_apart=lambda: False)) == 2


def test_two_lightnesses_from_the_top() -> None:
    top = np.zeros((40, 60), np.int32)
    top[10:30, 10:50] = 1
    _, white_black = _two_halves(230, 20)
    rgb = np.full((40, 60, 3), 150, np.uint8)
    rgb[10:30, 10:50] = white_black[30:50, 40:80]   # the halves meet at column 30
    assert two_lightnesses(rgb, top, [1], 2.0)
    rgb[10:30, 10:50] = 140   # one grey top, lit
    rgb[28:30, 10:50] = 20    # and a dark rim of its front face seen at an angle
    assert not two_lightnesses(rgb, top, [1], 2.0)
