"""The synthetic arm link that hides one part from one camera (sim/occlusion.py)."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import default_rig, transform_points
from tlessbot_ros.io.models import load_models
from tlessbot_ros.sim.occlusion import ArmOcclusionParams, occlude_frame
from tlessbot_ros.sim.simulator import SimParams, Simulator


@pytest.fixture(scope='module')
def frame(tless_models_dir):
    models = load_models(tless_models_dir, ids=[5, 11, 21, 25])
    return Simulator(models, rig=default_rig(320, 240), params=SimParams(parts_min=3),
                     seed=3).frame(0)


def test_the_part_is_hidden_from_the_side_only(frame):
    occluded, target = occlude_frame(frame, 'side', np.random.default_rng(0))
    assert target is not None
    side, before = occluded.views['side'], frame.views['side']
    assert side.gt[target].visib_fract == 0.0 and side.gt[target].px_count_visib == 0
    assert occluded.views['top'] is frame.views['top']            # the other view untouched
    assert frame.views['top'].gt[target].visib_fract >= 0.5
    link = side.instance != before.instance
    assert link.any() and np.all(side.instance[link] == -1)
    for g, g0 in zip(side.gt, before.gt):                          # masks only shrink
        assert not np.any(g.mask_visib & ~g0.mask_visib)
        assert g.px_count_visib == int(g.mask_visib.sum())
    assert np.array_equal(before.rgb, frame.views['side'].rgb)     # input not modified


def test_the_link_lies_at_its_height_above_the_table(frame):
    occluded, _ = occlude_frame(frame, 'side', np.random.default_rng(1))
    side = occluded.views['side']
    rows, cols = np.nonzero(side.depth_mm != frame.views['side'].depth_mm)
    z_m = side.depth_mm[rows, cols].astype(np.float64) / 1000.0
    rays = np.stack([cols, rows, np.ones_like(cols)], axis=1) @ np.linalg.inv(
        side.intrinsics.K).T
    heights = transform_points(side.T_world_camera, rays * z_m[:, None])[:, 2]
    np.testing.assert_allclose(heights, ArmOcclusionParams().height_m, atol=0.003)


def test_no_candidate_leaves_the_frame_alone(frame):
    same, target = occlude_frame(frame, 'side', np.random.default_rng(0), min_visib_other=1.1)
    assert target is None and same is frame
