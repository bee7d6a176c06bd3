import numpy as np
import pytest

from tlessbot_ros.sim.noise import DepthNoiseParams, add_depth_noise
from tlessbot_ros.sim.simulator import SimParams
from tlessbot_ros.sim.stereo_depth import StereoDepthParams

NO_HOLES = dict(projector_shadow=False, random_holes=0.0)


def _correlation(residual: np.ndarray, lag: int) -> float:
    """Autocorrelation of ``residual`` along the rows at ``lag`` px."""
    r = residual - residual.mean()
    return float((r[:, :-lag] * r[:, lag:]).mean() / (r * r).mean())


@pytest.mark.parametrize('z', [0.6, 1.1])
def test_smoothed_noise_is_correlated_over_several_pixels(z):
    depth = np.full((240, 320), z, np.float32)
    smoothed = add_depth_noise(depth, 615.0, np.random.default_rng(0),
                               DepthNoiseParams(kind='smoothed', **NO_HOLES))
    per_pixel = add_depth_noise(depth, 615.0, np.random.default_rng(0),
                                DepthNoiseParams(**NO_HOLES))
    assert (smoothed > 0).all()
    residual = smoothed.astype(float) - 1000 * z
    assert _correlation(residual, 4) > 0.6
    assert _correlation(per_pixel.astype(float) - 1000 * z, 4) < 0.4
    # stereo: the noise is in disparity, so in depth it grows with z squared (3 mm at 1.1 m)
    assert 0.0015 * z ** 2 < residual.std() / 1000 < 0.006 * z ** 2


def test_smoothed_depth_comes_in_disparity_steps():
    # without the smoothing, every depth is one of the 1/16 px disparity steps (at 1.1 m
    # 2.2 mm apart: wider than the 1 mm of the depth unit)
    params = DepthNoiseParams(kind='smoothed', stereo=StereoDepthParams(smooth_space_px=0.0),
                              **NO_HOLES)
    depth = np.tile(np.linspace(1.0, 1.2, 200, dtype=np.float32), (50, 1))
    out = add_depth_noise(depth, 615.0, np.random.default_rng(1), params)
    fb = 615.0 * 0.055
    levels = np.rint(1000 * fb / (np.arange(400, 600) / 16))
    assert np.isin(out, levels).all()
    assert len(np.unique(out)) < 0.6 * (out.max() - out.min())


def test_smoothed_edges_fatten_and_stay_sharp():
    # a box at 0.7 m in front of a wall at 0.8 m: the wall next to the box takes the box's
    # depth over ~2 px (the matching window), per-pixel depth keeps the wall or drops it
    depth = np.full((100, 200), 0.8, np.float32)
    depth[30:70, 80:120] = 0.7
    smoothed = add_depth_noise(depth, 615.0, np.random.default_rng(2),
                               DepthNoiseParams(kind='smoothed', **NO_HOLES))
    per_pixel = add_depth_noise(depth, 615.0, np.random.default_rng(2),
                                DepthNoiseParams(**NO_HOLES))
    rows = slice(40, 60)
    for out, fattened in ((smoothed, True), (per_pixel, False)):
        near = np.abs(out[rows].astype(float) - 700) < 20
        wall = np.abs(out[rows].astype(float) - 800) < 20
        assert near[:, 85:115].all() and wall[:, :70].all() and wall[:, 130:].all()
        assert near[:, 78].mean() > 0.9 if fattened else near[:, 78].mean() == 0
        assert near[:, 121].mean() > 0.9 if fattened else near[:, 121].mean() == 0
        assert not near[:, 75].any() and not near[:, 124].any()
    assert (smoothed == 0).sum() == 0 and (per_pixel[rows, 79:81] == 0).any()


def test_smoothed_keeps_shadow_and_highlight_holes():
    depth = np.full((100, 200), 0.8, np.float32)
    depth[:, 100:150] = 0.5
    highlight = np.zeros_like(depth)
    highlight[:, 110:130] = 1.0
    out = add_depth_noise(depth, 615.0, np.random.default_rng(3),
                          DepthNoiseParams(kind='smoothed', random_holes=0.0),
                          highlight=highlight, ir_dropout=np.full_like(depth, 0.35))
    assert (out[:, 85:98] == 0).all()          # the second imager's shadow, 25 px wide
    assert (out[:, 110:130] == 0).mean() > 0.5
    assert (out[:, 20:70] == 0).mean() == 0


def test_scale_zero_is_clean_for_both_kinds():
    depth = np.full((40, 60), 0.8, np.float32)
    depth[10:30, 20:40] = 0.75
    for kind in ('per_pixel', 'smoothed'):
        out = add_depth_noise(depth, 615.0, np.random.default_rng(4),
                              DepthNoiseParams(kind=kind, scale=0.0, projector_shadow=False))
        assert np.array_equal(out, np.rint(depth * 1000).astype(np.uint16))


def test_default_is_per_pixel_and_unknown_kind_refused():
    # the simulator's frames keep the per-pixel kind unless asked (test/golden holds its bytes)
    assert DepthNoiseParams().kind == 'per_pixel'
    assert SimParams().depth_noise.kind == 'per_pixel'
    depth = np.full((60, 80), 0.9, np.float32)
    per_pixel = add_depth_noise(depth, 615.0, np.random.default_rng(5), DepthNoiseParams())
    smoothed = add_depth_noise(depth, 615.0, np.random.default_rng(5),
                               DepthNoiseParams(kind='smoothed'))
    assert not np.array_equal(per_pixel, smoothed)   # the kind is not ignored
    with pytest.raises(ValueError, match='per_pixel'):
        DepthNoiseParams(kind='stereo')
