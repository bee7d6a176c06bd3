"""The depth cue's table reaches up to the table plane fit's noise band (cues.depth_cue,
``table_band_m``): smoothed stereo depth raises part-sized table patches a few millimetres,
and where they rise above the per-pixel table height, a coloured table square there was a
part (docs/bench/unseen-false-parts.md)."""
from __future__ import annotations

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics
from tlessbot_ros.core.localise import SegmentationParams, segment
from tlessbot_ros.core.localise.cues import depth_cue

CAMERA_HEIGHT_M = 1.1
NOISE_AT_1M_M = 0.0013       # what the plane fit measures on such depth
BAND_AT_1M_M = 3.0 * NOISE_AT_1M_M


def _heights(h: int = 120, w: int = 160) -> np.ndarray:
    """A table in 1 mm steps (most pixels 0, a quarter +-1 mm: robust deviation 1.5 mm) with
    a 4 mm patch (the smoothed noise's) and a 15 mm part."""
    rng = np.random.default_rng(0)
    height = rng.choice([-0.001, 0.0, 0.0, 0.001], size=(h, w)).astype(np.float32)
    height[20:40, 20:50] = 0.004
    height[70:90, 100:130] = 0.015
    return height


def test_a_patch_within_the_band_is_table_and_a_part_above_it_is_not():
    height = _heights()
    params = SegmentationParams()
    plain = depth_cue(height, params)
    assert not plain.table[25:35, 25:45].any()      # 4 mm: above twice the deviation
    band = np.full(height.shape, BAND_AT_1M_M * CAMERA_HEIGHT_M ** 2, np.float32)   # 4.7 mm
    banded = depth_cue(height, params, table_band_m=band)
    assert banded.table[25:35, 25:45].all()
    assert not banded.table[75:85, 105:125].any()   # the part stays off the table
    assert np.array_equal(banded.candidate, plain.candidate)   # object heights unchanged


def test_segment_no_longer_takes_a_raised_coloured_square_for_a_part():
    height = _heights()
    h, w = height.shape
    f = 150.0
    intrinsics = CameraIntrinsics(w, h, np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2],
                                                  [0, 0, 1]]))
    T_world_camera = np.diag([1.0, -1.0, -1.0, 1.0])     # looking straight down
    T_world_camera[2, 3] = CAMERA_HEIGHT_M
    depth = (CAMERA_HEIGHT_M - height).astype(np.float32)
    rgb = np.full((h, w, 3), (150, 150, 145), np.uint8)
    rgb[20:40, 20:50] = (235, 120, 175)   # a pink table square over the raised patch
    seen = dict(depth_m=depth, intrinsics=intrinsics, T_world_camera=T_world_camera,
                split_by_depth=False)
    assert segment(rgb, **seen).labels[25:35, 25:45].any()
    banded = segment(rgb, table_band_at_1m_m=BAND_AT_1M_M, **seen)
    assert not banded.labels[25:35, 25:45].any()
    assert banded.labels[75:85, 105:125].any()        # the part is still found
