"""Augmentation of rendered training crops, box crops with their angular size, and the
background class: small synthetic data only."""
from __future__ import annotations

import numpy as np
import pytest

from tlessbot_ros.core.common import nearest_rotation, rotation_about_axis
from tlessbot_ros.core.recognise import (
    BACKGROUND_ID,
    UNKNOWN_ID,
    HogParams,
    LinearClassifier,
    describe_regions,
)
from tlessbot_ros.core.recognise.augment import (
    PhotometricParams,
    loose_box,
    photometric,
    texture_background,
)
from tlessbot_ros.core.recognise.hog import box_size_features


def _image(seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)


def test_photometric_keeps_shape_and_is_deterministic_per_generator():
    image = _image()
    a = photometric(image, np.random.default_rng(3))
    b = photometric(image, np.random.default_rng(3))
    c = photometric(image, np.random.default_rng(4))
    assert a.shape == image.shape and a.dtype == np.uint8
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_photometric_identity_settings_change_nothing():
    identity = PhotometricParams(exposure=(1, 1), white_balance=0, gamma=(1, 1),
                                 contrast=(1, 1), blur_prob=0, noise_sigma=(0, 0), jpeg_prob=0,
                                 grey_prob=0)
    image = np.full((8, 8, 3), 128, np.uint8)
    out = photometric(image, np.random.default_rng(0), params=identity)
    assert np.abs(out.astype(int) - 128).max() <= 1


def test_photometric_exposure_darkens_and_brightens():
    image = np.full((16, 16, 3), 100, np.uint8)
    dark = PhotometricParams(exposure=(0.5, 0.5), white_balance=0, gamma=(1, 1), contrast=(1, 1),
                             blur_prob=0, noise_sigma=(0, 0), jpeg_prob=0, grey_prob=0)
    out = photometric(image, np.random.default_rng(0), params=dark)
    assert abs(float(out.mean()) - 50) < 2


def test_photometric_rejects_bad_input_and_ranges():
    with pytest.raises(ValueError, match='uint8'):
        photometric(np.zeros((4, 4, 3), np.float32), np.random.default_rng(0))
    with pytest.raises(ValueError, match='gamma'):
        PhotometricParams(gamma=(2.0, 1.0))
    with pytest.raises(ValueError, match='jpeg_prob'):
        PhotometricParams(jpeg_prob=1.5)


def test_loose_box_holds_most_of_the_tight_box_and_grows_it():
    rng = np.random.default_rng(1)
    for _ in range(200):
        x, y, w, h = loose_box((100, 50, 40, 20), rng, grow=(0.0, 0.3), shift=0.1)
        assert 40 <= w <= 52 + 1 and 20 <= h <= 26 + 1
        assert abs((x + w / 2) - 120) <= 0.1 * 40 + 1
        assert abs((y + h / 2) - 60) <= 0.1 * 20 + 1
    with pytest.raises(ValueError):
        loose_box((0, 0, 0, 5), rng)


def test_texture_backgrounds_are_in_range_and_vary():
    rng = np.random.default_rng(2)
    images = [texture_background((30, 40), rng) for _ in range(12)]
    assert all(im.shape == (30, 40, 3) and im.dtype == np.float32 for im in images)
    assert all(0.0 <= im.min() and im.max() <= 1.0 for im in images)
    assert len({round(float(im.mean()), 3) for im in images}) > 6


def test_box_size_is_log_angular_size_and_scale_invariant():
    size = box_size_features([(0, 0, 60, 30), (5, 5, 30, 60)], 600.0)
    assert np.allclose(size[0], [np.log(0.1), np.log(0.05)])
    assert np.allclose(size[0], size[1])  # longer side first, whatever the orientation
    # twice the focal length and twice the pixels: the same angle
    assert np.allclose(box_size_features([(0, 0, 120, 60)], 1200.0), size[:1])
    with pytest.raises(ValueError):
        box_size_features([(0, 0, 1, 1)], 0.0)


def test_box_crops_ignore_the_mask_and_append_the_size():
    image = _image(5)
    mask = np.zeros(image.shape[:2], bool)
    mask[10:30, 10:40] = True
    mask[15:20, 15:20] = False  # a hole: a box crop does not see it
    box_params = HogParams(crop_mode='box', box_size=True)
    with_mask = describe_regions(image, None, [mask], params=box_params, focal_px=500.0)
    by_box = describe_regions(image, [(10, 10, 30, 20)], None, params=box_params,
                              focal_px=500.0)
    assert with_mask.shape == (1, box_params.hog_dim + 2) == by_box.shape
    assert np.allclose(with_mask, by_box)
    assert np.allclose(by_box[0, -2:], np.log([30 / 500.0, 20 / 500.0]))
    masked = describe_regions(image, None, [mask], params=HogParams())
    assert not np.allclose(masked, by_box[:, :-2])
    with pytest.raises(ValueError, match='crop_mode'):
        HogParams(crop_mode='ellipse')


def test_a_background_class_answers_unknown_and_is_never_a_candidate():
    small = HogParams(cell_px=30, block_cells=1, bins=2)  # 8 HOG values
    model = LinearClassifier(weights=np.zeros((small.feature_dim, 3), np.float32),
                             intercepts=np.zeros(3, np.float32),
                             class_ids=np.array([BACKGROUND_ID, 4, 7]), hog_params=small)
    scores = np.array([[5.0, 1.0, 0.0], [0.0, 3.0, 1.0]], np.float32)
    prediction = model.predict_scores(scores)
    assert prediction.class_ids.tolist() == [UNKNOWN_ID, 4]
    ranked = model.ranked_classes(scores, 3)
    assert ranked.shape == (2, 2) and BACKGROUND_ID not in ranked
    assert ranked[0].tolist() == [4, 7]


def test_nearest_rotation_projects_near_rotations_and_refuses_others():
    R = rotation_about_axis(np.array([1.0, 2.0, 3.0]), 0.7)
    assert np.allclose(nearest_rotation(R), R)
    scaled = R * 1.005  # det 1.015, as in BOP ground-truth files
    projected = nearest_rotation(scaled)
    assert projected is not None
    assert np.allclose(projected @ projected.T, np.eye(3), atol=1e-12)
    assert np.isclose(np.linalg.det(projected), 1.0)
    assert np.allclose(projected, R, atol=1e-9)
    assert nearest_rotation(-R) is None            # a reflection
    assert nearest_rotation(R * 1.3) is None       # far from a rotation
    assert nearest_rotation(np.full((3, 3), np.nan)) is None
