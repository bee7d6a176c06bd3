import numpy as np
import pytest

from tlessbot_ros.sim.noise import (
    DepthNoiseParams,
    add_depth_noise,
    spread_depth_kind,
    stereo_region,
    stereo_shadow,
)


def test_sigma_grows_with_z_squared():
    rng = np.random.default_rng(0)
    params = DepthNoiseParams(projector_shadow=False, random_holes=0.0)
    stds = []
    for z in (0.5, 1.0):
        depth = np.full((240, 320), z, np.float32)
        noisy = add_depth_noise(depth, 615.0, rng, params).astype(np.float64) / 1000.0
        stds.append((noisy[noisy > 0] - z).std())
    assert stds[1] == pytest.approx(0.07 / (615 * 0.055), rel=0.25)  # ~2 mm at 1 m
    assert 2.5 < stds[1] / stds[0] < 5.5  # ~4 = (1.0 / 0.5)^2, blurred by 1 mm quantisation
    double = add_depth_noise(np.full((240, 320), 1.0, np.float32), 615.0, rng,
                             DepthNoiseParams(scale=2.0, projector_shadow=False,
                                              random_holes=0.0)).astype(float) / 1000.0
    assert (double[double > 0] - 1.0).std() == pytest.approx(2 * stds[1], rel=0.2)


def test_stereo_shadow_left_of_a_step():
    # A box at 0.5 m in front of a wall at 1.0 m: the second imager sits to the right (+x), so
    # the wall just left of the box is hidden from it: a band of f * b * (1/0.5 - 1/1.0) px.
    depth = np.full((10, 200), 1.0, np.float32)
    depth[:, 100:150] = 0.5
    shadow = stereo_shadow(depth, 615.0, 0.055)
    width = 615.0 * 0.055 * (1 / 0.5 - 1 / 1.0)
    cols = np.nonzero(shadow[5])[0]
    assert cols.max() == 99
    assert len(cols) == pytest.approx(width, abs=1.5)
    assert not shadow[:, 100:].any()


def test_edges_and_highlights_make_holes():
    rng = np.random.default_rng(1)
    depth = np.full((100, 100), 0.8, np.float32)
    depth[:, 50:] = 0.7
    out = add_depth_noise(depth, 615.0, rng, DepthNoiseParams(projector_shadow=False,
                                                              random_holes=0.0))
    assert (out[:, 49:51] == 0).mean() > 0.45  # the two columns at the step, p = 0.6
    assert (out[:, :40] == 0).mean() < 0.01
    highlight = np.zeros_like(depth)
    highlight[:, :20] = 1.0
    out = add_depth_noise(depth, 615.0, rng, DepthNoiseParams(projector_shadow=False,
                                                              random_holes=0.0),
                          highlight=highlight, ir_dropout=np.full_like(depth, 0.35))
    assert (out[:, :20] == 0).mean() > 0.5
    assert (out[:, 25:45] == 0).mean() < 0.01



@pytest.mark.parametrize('share', [0.0, 0.25, 0.5, 0.8, 1.0])
def test_spread_depth_kind_gives_the_share_spread_evenly(share):
    kinds = [spread_depth_kind(k, share) for k in range(100)]
    assert kinds.count('smoothed') == round(100 * share)
    # any 10 consecutive items hold the share to within one
    for start in range(0, 91):
        assert abs(kinds[start:start + 10].count('smoothed') - 10 * share) <= 1
    with pytest.raises(ValueError, match='smoothed_share'):
        spread_depth_kind(0, -0.1)


def test_stereo_region_takes_the_raised_ring_around_the_part():
    from tlessbot_ros.core.common import look_at

    K = np.array([[600.0, 0, 40], [0, 600.0, 30], [0, 0, 1]])
    T = look_at(np.array([0.0, 0.0, 0.8]), np.zeros(3), np.array([0.0, 1.0, 0.0]))
    depth = np.full((60, 80), 0.8, np.float32)          # the table, seen from straight above
    part = np.zeros((60, 80), bool)
    part[20:40, 30:50] = True
    depth[part] = 0.79                                   # a 10 mm block
    depth[19, 30:50] = 0.79                              # the fattened edge above it
    region = stereo_region(part, depth, K, T, grow_px=1)
    assert region[part].all() and region[19, 30:50].all()
    assert region.sum() == part.sum() + 20               # the table stays out
    assert np.array_equal(stereo_region(part, depth, K, T, grow_px=0), part)
