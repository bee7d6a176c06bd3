"""A part a few pixels across is completed by the full-resolution depth
(core/localise/small_parts.py); a blob the depth calls table keeps its own; a thin blob larger
than any part can look is divided (core/localise/part_scale.py)."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.localise.small_parts import small_blobs_from_depth

K = np.array([[600.0, 0, 20], [0, 600.0, 20], [0, 0, 1]])
T = np.diag([1.0, -1.0, -1.0, 1.0])   # 0.6 m above the table, looking straight down
T[2, 3] = 0.6


def _scene():
    depth = np.full((40, 40), 0.6, np.float32)
    depth[10:20, 12:21] = 0.594          # a part 6 mm high, 9 x 10 px
    labels = np.zeros((40, 40), np.uint16)
    labels[12:22, 14:22] = 1             # its blob, two cue-scale pixels off
    labels[30:36, 2:8] = 2               # a shadow: table in the depth
    labels[2:30, 28:38] = 3              # a large part: not touched
    boxes = np.array([[14, 12, 8, 10], [2, 30, 6, 6], [28, 2, 10, 28]], np.int32)
    areas = np.array([80, 36, 280], np.int64)
    return depth, labels, boxes, areas


def test_a_small_blob_grows_to_the_depths_outline_a_shadow_and_a_large_blob_keep_theirs():
    depth, labels, boxes, areas = _scene()
    before = labels.copy()
    new_boxes, new_areas = small_blobs_from_depth(labels, boxes, areas, depth, K, T, 100,
                                                  0.0025, reach_px=2)
    # the part's 9 x 10 px and the blob's two rows below it that the depth calls table
    assert new_boxes[0].tolist() == [12, 10, 10, 12]
    assert np.array_equal(labels == 1, (depth < 0.595) | (before == 1))
    assert new_areas[0] == np.count_nonzero(labels == 1)
    assert np.array_equal(labels == 2, before == 2) and new_boxes[1].tolist() == [2, 30, 6, 6]
    assert np.array_equal(labels == 3, before == 3) and new_areas[2] == 280
    # the inputs' boxes and areas are not changed
    assert boxes[0].tolist() == [14, 12, 8, 10]


def test_pixels_without_depth_stay_with_the_part_and_neighbours_are_not_taken():
    depth, labels, boxes, areas = _scene()
    depth[14:18, 15:19] = 0.0            # a dark patch: no depth
    labels[10:12, 12:21] = 4             # a neighbour over the part's top rows
    small_blobs_from_depth(labels, boxes, areas, depth, K, T, 100, 0.0025, reach_px=2)
    assert (labels[14:18, 15:19] == 1).all()
    assert (labels[10:12, 12:21] == 4).all()


def _two_plates():
    """Two thin plates (4 mm, 40 x 30 px each, 0.6 m away) touching at a corner."""
    mask = np.zeros((90, 110), bool)
    mask[10:40, 10:50] = True
    mask[39:69, 49:89] = True
    height = np.where(mask, 0.004, 0.0).astype(np.float32)
    depth = np.where(mask, 0.596, 0.6).astype(np.float32)
    return mask, height, depth


def test_a_thin_blob_larger_than_any_part_can_look_is_divided():
    from tlessbot_ros.core.localise import SegmentationParams, split_touching
    from tlessbot_ros.core.localise.part_scale import largest_part_px_m2, several_parts

    mask, height, depth = _two_plates()
    # the largest part covers 1500 px at 0.596 m: the blob (2400 px) is two parts
    params = SegmentationParams(largest_part_px_m2=1500 * 0.596 ** 2)
    labels = split_touching(mask, height_m=height, depth_m=depth, params=params)
    assert labels.max() == 2
    assert len(np.unique(labels[10:40, 10:48])) == 1 and len(np.unique(labels[41:69, 51:89])) == 1
    # a thin blob is kept whole otherwise (its holes and lobes are no seams)
    unknown = split_touching(mask, height_m=height, depth_m=depth, params=SegmentationParams())
    assert unknown.max() == 1
    large = SegmentationParams(largest_part_px_m2=2500 * 0.596 ** 2)
    assert split_touching(mask, height_m=height, depth_m=depth, params=large).max() == 1
    assert not several_parts(mask, np.zeros_like(depth), params)   # no depth: no verdict
    # a plate 60 x 40 x 4 mm is the largest of these; at the corner of a 640 x 480 image
    # seen with f = 600 px its outline is stretched by at most 1 / cos(34 deg)
    K = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
    outline = np.sqrt(0.0024 ** 2 + 0.00016 ** 2 + 0.00024 ** 2)
    assert largest_part_px_m2(np.array([[0.06, 0.04, 0.004], [0.02, 0.01, 0.01]]), K) == \
        pytest.approx(600 * 600 * outline * np.hypot(1, np.hypot(320 / 600, 240 / 600)))
