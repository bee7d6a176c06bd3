"""Touching parts in a pile: the side view's instances the top view sees as one blob."""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.localise.calibrated_fusion import _side_pieces_of_blob
from tlessbot_ros.core.localise.fusion_result import FusionParams
from tlessbot_ros.core.localise.part_length import (
    ViewDepth,
    fits_a_part,
    longer_than_parts,
    table_extents_m,
    table_length_m,
)
from tlessbot_ros.core.localise.part_scale import shared_border_ratio
from tlessbot_ros.core.localise.segmentation import Segmentation

# a camera 1 m above the table looking straight down (x right, y towards -y of the table)
K = np.array([[500.0, 0.0, 30.0], [0.0, 500.0, 20.0], [0.0, 0.0, 1.0]])
T_DOWN = np.array([[1.0, 0, 0, 0], [0, -1.0, 0, 0], [0, 0, -1.0, 1.0], [0, 0, 0, 1.0]])


def _two_halves(whole_px: float, longest_m: float = 0.05,
                depth: ViewDepth | None = None,
                labels: np.ndarray | None = None) -> tuple[np.ndarray, Segmentation]:
    """A side blob cut in two instances at distance cores (no depth group; by default two
    400 px squares side by side), the parts' smallest whole blob ``whole_px`` and largest
    extent ``longest_m``."""
    if labels is None:
        labels = np.zeros((40, 60), np.uint16)
        labels[10:30, 10:30], labels[10:30, 30:50] = 1, 2
    seg = Segmentation(labels=labels, boxes=np.array([[10, 10, 20, 20], [30, 10, 20, 20]],
                                                     np.int32),
                       areas=np.array([400, 400], np.int64), foreground=labels > 0,
                       depth_groups=np.zeros(2, np.int32), thin=np.zeros(2, bool),
                       whole_parts=np.array([[longest_m, whole_px, 60.0]]), depth=depth)
    return labels > 0, seg


def test_two_instances_that_could_each_be_a_whole_part_stay_apart() -> None:
    blob, side = _two_halves(whole_px=300.0)
    apart = _side_pieces_of_blob(blob, side.labels, side, FusionParams(), owners=[1])
    assert len(apart) == 2
    assert np.array_equal(apart[0], side.labels == 1)
    # main's rule: one top blob over both, no depth seam: one part
    off = FusionParams(apart_each_whole=0.0, apart_longer_than_parts=0.0)
    assert _side_pieces_of_blob(blob, side.labels, side, off, owners=[1]) == []
    # several top blobs over it: their predictions decide, not the parts' sizes
    assert _side_pieces_of_blob(blob, side.labels, side, FusionParams(), owners=[1, 2]) == []
    # halves smaller than any whole part: two pieces of one part
    blob, side = _two_halves(whole_px=500.0)
    assert _side_pieces_of_blob(blob, side.labels, side, FusionParams(), owners=[1]) == []


def test_two_instances_longer_than_any_part_stay_apart() -> None:
    # 40 px at 0.98 m: 7.8 cm on the table, 2 cm above it
    depth = ViewDepth(np.full((40, 60), 0.98), K, T_DOWN)
    blob, side = _two_halves(whole_px=500.0, longest_m=0.05, depth=depth)
    assert len(_side_pieces_of_blob(blob, side.labels, side, FusionParams(), owners=[1])) == 2
    off = FusionParams(apart_longer_than_parts=0.0)
    assert _side_pieces_of_blob(blob, side.labels, side, off, owners=[1]) == []
    # a part 8 cm long could be the two together
    blob, side = _two_halves(whole_px=500.0, longest_m=0.08, depth=depth)
    assert _side_pieces_of_blob(blob, side.labels, side, FusionParams(), owners=[1]) == []


def test_a_region_on_the_table_has_the_length_of_its_long_side() -> None:
    depth = ViewDepth(np.full((40, 60), 0.98), K, T_DOWN)
    mask = np.zeros((40, 60), bool)
    mask[15:25, 5:55] = True   # 50 x 10 px: 9.8 x 2 cm
    xy = depth.table_xy(mask)
    assert len(xy) == 500 and np.allclose(np.sort(np.unique(np.round(xy[:, 0], 6)))[[0, -1]],
                                          [-25 * 0.98 / 500, 24 * 0.98 / 500])
    assert abs(table_length_m(xy) - 0.098 * 0.98) < 0.004
    # turned by 90 degrees on the table: the same length
    assert abs(table_length_m(xy[:, ::-1]) - table_length_m(xy)) < 1e-9
    assert longer_than_parts(depth, np.array([[0.08, 1.0, 1.0]]), 1.1, mask)
    assert not longer_than_parts(depth, np.array([[0.09, 1.0, 1.0]]), 1.1, mask)
    # the table itself, and no depth: no length
    assert table_length_m(ViewDepth(np.full((40, 60), 1.0), K, T_DOWN).table_xy(mask)) == 0.0
    assert not longer_than_parts(None, np.array([[0.01, 1.0, 1.0]]), 1.1, mask)


def test_a_thin_region_fits_a_part_no_shorter_and_no_narrower_than_it() -> None:
    # a camera 1 m above the table looking down: 50 x 10 px on the table is 9.8 x 2 cm
    H_table = K @ np.linalg.inv(T_DOWN)[:3][:, [0, 1, 3]]
    mask = np.zeros((40, 60), bool)
    mask[15:25, 5:55] = True
    length, width = table_extents_m(np.argwhere(mask)[:, ::-1] / 500.0)
    assert abs(length - 0.098) < 0.003 and abs(width - 0.019) < 0.003
    assert fits_a_part(mask, (0, 0), H_table, ((0.1, 0.02), (0.04, 0.04)), 1.2)
    assert fits_a_part(mask[:, :30], (0, 30), H_table, ((0.05, 0.02),), 1.2)
    # too long for the plate, too wide for the wire; and the same turned on the table
    assert not fits_a_part(mask, (0, 0), H_table, ((0.07, 0.05), (0.2, 0.01)), 1.2)
    assert not fits_a_part(mask.T, (0, 0), H_table, ((0.07, 0.05), (0.2, 0.01)), 1.2)


def test_two_part_sized_pieces_cut_across_one_part_are_one_part() -> None:
    # a bar 36 px tall cut across its 24 px width: two 36 x 12 px halves meeting along 36 px
    labels = np.zeros((40, 60), np.uint16)
    labels[2:38, 18:30], labels[2:38, 30:42] = 1, 2
    blob, side = _two_halves(whole_px=300.0, labels=labels)
    assert shared_border_ratio(labels == 1, labels == 2) >= 36 / np.sqrt(36 * 12)
    assert _side_pieces_of_blob(blob, side.labels, side, FusionParams(), owners=[1]) == []
    # with the guard off, each half could be a whole part: apart (main's rule)
    off = FusionParams(whole_cut_border=0.0)
    assert len(_side_pieces_of_blob(blob, side.labels, side, off, owners=[1])) == 2
    # two squares that touch along 8 px of their sides: two parts in a pile, still apart
    labels = np.zeros((40, 60), np.uint16)
    labels[2:22, 10:30], labels[14:34, 30:50] = 1, 2
    blob, side = _two_halves(whole_px=300.0, labels=labels)
    assert shared_border_ratio(labels == 1, labels == 2) < 0.5
    assert len(_side_pieces_of_blob(blob, side.labels, side, FusionParams(), owners=[1])) == 2
    assert shared_border_ratio(labels == 1, np.zeros_like(labels, bool)) == 0.0
