import numpy as np
import pytest

from tlessbot_ros.core.recognise import normalise_crop
from tlessbot_ros.io.models import load_models
from tlessbot_ros.sim.turntable import Turntable, TurntableParams, square_crop, write_samples


@pytest.fixture(scope='module')
def models(tless_models_dir):
    return load_models(tless_models_dir, [5, 19])


def test_protocol_counts_and_crops(models):
    params = TurntableParams(step_deg=90, positions=2, augmentations=1)
    table = Turntable(models, params=params, seed=3)
    samples = list(table.samples())
    assert len(samples) == len(table) == 2 * 2 * 4 * 2
    assert {s.obj_id for s in samples} == {5, 19}
    assert sorted({s.angle_deg for s in samples}) == [0, 90, 180, 270]
    for sample in samples:
        assert sample.rgb.dtype == np.uint8 and sample.rgb.shape[:2] == sample.mask.shape
        # the part covers a good share of its window; D415-like apparent size (tens of px)
        assert 0.1 < sample.mask.mean() <= 1.0
        assert 20 <= max(sample.mask.shape) <= 400
        crop = normalise_crop(sample.rgb, mask=sample.mask)
        assert crop.shape == (60, 60) and crop.max() > 200


def test_deterministic_and_order_independent(models):
    params = TurntableParams(step_deg=45, positions=1, augmentations=1)
    a = list(Turntable(models, params=params, seed=7).views(19, 0, steps=[3]))
    b = list(Turntable({19: models[19]}, params=params, seed=7).views(19, 0, steps=[3]))
    full = [s for s in Turntable(models, params=params, seed=7).views(19, 0)
            if s.angle_deg == 135.0]
    for x, y, z in zip(a, b, full):
        assert np.array_equal(x.rgb, y.rgb) and np.array_equal(x.mask, z.mask)
        assert np.array_equal(x.rgb, z.rgb)
    c = list(Turntable(models, params=params, seed=8).views(19, 0, steps=[3]))
    assert not np.array_equal(a[0].rgb, c[0].rgb)


def test_views_differ_with_angle(models):
    params = TurntableParams(step_deg=90, positions=1, augmentations=0)
    views = list(Turntable(models, params=params).views(5, 0))
    crops = [normalise_crop(v.rgb, mask=v.mask).astype(float) for v in views]
    assert np.abs(crops[0] - crops[2]).mean() > 5.0


def test_write_samples(models, tmp_path):
    params = TurntableParams(step_deg=180, positions=1, augmentations=0)
    table = Turntable(models, params=params)
    count = write_samples(table.samples(), tmp_path)
    assert count == 4
    lines = (tmp_path / 'labels.csv').read_text().splitlines()
    assert lines[0].startswith('file,obj_id') and len(lines) == 5
    assert len(list((tmp_path / '5').glob('*.png'))) == 2
    rgba = square_crop(next(table.views(19, 0)))
    assert rgba.shape == (60, 60, 4) and rgba[..., 3].max() == 255 and rgba[0, 0, 3] == 0


def test_param_errors():
    with pytest.raises(ValueError, match='elevation'):
        TurntableParams(elevation_deg=(10.0, 100.0))
    with pytest.raises(ValueError, match='step_deg'):
        TurntableParams(step_deg=0)


def test_samples_carry_depth_and_pose(models):
    from tlessbot_ros.core.recognise import region_points_world

    params = TurntableParams(step_deg=120, positions=1, augmentations=2)
    for sample in Turntable(models, params=params, seed=2).views(5, 0):
        assert sample.depth_m.shape == sample.mask.shape and sample.depth_m.dtype == np.float32
        points = region_points_world(sample.depth_m, sample.mask, sample.K,
                                     sample.T_world_camera, max_points=0)
        assert len(points) > 0.5 * sample.mask.sum()  # noise drops only a few pixels
        top = models[5].vertices.max(axis=0) - models[5].vertices.min(axis=0)
        # every visible point of the part lies above the plate, below its largest side
        assert np.percentile(points[:, 2], 5) > -0.003
        assert np.percentile(points[:, 2], 95) < top.max() + 0.005
        # the plate around the part (outside the mask) is the table plane z = 0
        plate = region_points_world(sample.depth_m, ~sample.mask, sample.K,
                                    sample.T_world_camera)
        if len(plate) > 50:
            assert abs(np.median(plate[:, 2])) < 0.003


def _rough_share(sample) -> float:
    """Share of horizontally neighbouring part pixels whose depths differ (1 mm steps)."""
    d = sample.depth_m
    both = (d[:, 1:] > 0) & (d[:, :-1] > 0) & sample.mask[:, 1:] & sample.mask[:, :-1]
    return float((d[:, 1:] != d[:, :-1])[both].mean())


def test_a_share_of_the_views_gets_stereo_like_depth(models):
    plain = TurntableParams(step_deg=90, positions=1, augmentations=0)
    mixed = TurntableParams(step_deg=90, positions=1, augmentations=0,
                            smoothed_depth_share=0.5)
    before = list(Turntable(models, params=plain, seed=3).views(5, 0))
    after = list(Turntable(models, params=mixed, seed=3).views(5, 0))
    assert [s.depth_kind for s in before] == ['per_pixel'] * 4
    assert [s.depth_kind for s in after] == ['per_pixel', 'smoothed'] * 2
    for old, new in zip(before, after):
        # the same view, only its depth model differs
        assert np.array_equal(old.rgb, new.rgb)
        if new.depth_kind == 'per_pixel':
            assert np.array_equal(old.depth_m, new.depth_m)
            assert np.array_equal(old.mask, new.mask)
        else:   # smoothed: neighbours mostly share a depth step, per-pixel noise does not
            assert _rough_share(new) < 0.8 * _rough_share(old)
            # the region takes the fattened edge where the depth rises, as a localiser's does
            grown = new.mask & ~old.mask
            assert not (old.mask & ~new.mask).any() and 0 < grown.sum() < 0.3 * old.mask.sum()
    with pytest.raises(ValueError, match='smoothed_depth_share'):
        TurntableParams(smoothed_depth_share=1.5)
