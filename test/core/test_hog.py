import numpy as np
import pytest

from tlessbot_ros.core.recognise import (
    HogParams,
    describe_regions,
    hog_features,
    normalise_crop,
)


def _scene(brightness: float = 0.8, shift=(0, 0), size=(240, 320)):
    """A grey L-shaped part with a shaded face on a textured background."""
    rng = np.random.default_rng(1)
    image = rng.uniform(0.0, 1.0, (*size, 3)) * 255
    mask = np.zeros(size, bool)
    r, c = 60 + shift[0], 90 + shift[1]
    mask[r:r + 80, c:c + 40] = True
    mask[r + 50:r + 80, c:c + 100] = True
    image[mask] = brightness * 255
    image[r:r + 50, c:c + 20][mask[r:r + 50, c:c + 20]] = brightness * 160  # shaded face
    return image.astype(np.uint8), mask


def test_shape_and_dim():
    image, mask = _scene()
    crop = normalise_crop(image, mask=mask)
    assert crop.shape == (60, 60) and crop.dtype == np.uint8
    params = HogParams()
    features = hog_features(crop[None])
    # 9x9 blocks of 2x2 cells x 4 bins (paper's 6x6 cells, 4 bins)
    assert features.shape == (1, 9 * 9 * 4 * 4) == (1, params.feature_dim)
    assert features.dtype == np.float32 and np.isfinite(features).all()


def test_masked_crop_ignores_background_and_colour():
    image, mask = _scene(0.8)
    other = np.random.default_rng(7).integers(0, 255, image.shape, dtype=np.uint8)
    other[mask] = image[mask]
    a = normalise_crop(image, mask=mask)
    assert np.array_equal(a, normalise_crop(other, mask=mask))
    assert (a[0, :] == 0).all()  # background row is 0
    dark, _ = _scene(0.25)  # the same part in a dark PLA
    b = normalise_crop(dark, mask=mask)
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 2


def test_translation_invariance():
    image, mask = _scene()
    moved, moved_mask = _scene(shift=(40, 70))
    f = describe_regions(image, masks=[mask])
    g = describe_regions(moved, masks=[moved_mask])
    np.testing.assert_allclose(f, g, atol=1e-6)


def test_different_shapes_differ():
    image, mask = _scene()
    flipped = mask[:, ::-1]
    f = describe_regions(image, masks=[mask])
    g = describe_regions(image[:, ::-1], masks=[flipped])
    h = describe_regions(image[::-1], masks=[mask[::-1]])
    assert np.linalg.norm(f - g) > 1.0 and np.linalg.norm(f - h) > 1.0


def test_box_without_mask_and_batch_order():
    image, mask = _scene()
    boxes = [(90, 60, 100, 80), (0, 0, 50, 30), (300, 220, 40, 40)]  # last one leaves the image
    batch = describe_regions(image, boxes=boxes)
    assert batch.shape == (3, HogParams().feature_dim)
    single = describe_regions(image, boxes=[boxes[1]])
    np.testing.assert_array_equal(batch[1], single[0])


@pytest.mark.parametrize('cell, bins', [(4, 2), (10, 5), (20, 3)])
def test_configurable_cells_and_bins(cell, bins):
    params = HogParams(cell_px=cell, bins=bins)
    image, mask = _scene()
    features = describe_regions(image, masks=[mask], params=params)
    assert features.shape == (1, params.feature_dim)


def test_errors():
    with pytest.raises(ValueError, match='multiple of cell_px'):
        HogParams(cell_px=7)
    with pytest.raises(ValueError, match='bins'):
        HogParams(bins=1)
    image, mask = _scene()
    with pytest.raises(ValueError, match='empty'):
        normalise_crop(image, mask=np.zeros_like(mask))
    with pytest.raises(ValueError, match='positive width'):
        normalise_crop(image, (0, 0, 0, 10))
    with pytest.raises(ValueError, match='uint8'):
        hog_features(np.zeros((1, 60, 60), np.float32))
    with pytest.raises(ValueError, match='shape'):
        normalise_crop(image, mask=mask[:10])
