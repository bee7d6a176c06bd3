"""One mask -> box helper (core.common.mask_box) behind describe, normalise_crop and the
shape features' point window."""
import numpy as np
import pytest

from tlessbot_ros.core.common import make_transform, mask_box
from tlessbot_ros.core.recognise import (
    HogParams,
    LinearClassifier,
    ShapeParams,
    normalise_crop,
    region_points_world,
)

HOG = HogParams(cell_px=20, bins=2)


def _frame(size=64):
    rng = np.random.default_rng(3)
    image = rng.integers(0, 255, (size, size, 3), dtype=np.uint8)
    depth = rng.uniform(0.95, 0.98, (size, size)).astype(np.float32)
    mask = np.zeros((size, size), bool)
    mask[10:30, 20:51] = True
    mask[12, 20] = False
    K = np.array([[300.0, 0, size / 2], [0, 300.0, size / 2], [0, 0, 1.0]])
    T = make_transform(np.diag([1.0, -1.0, -1.0]), np.array([0.0, 0.0, 1.0]))
    return image, depth, mask, K, T


def _model(shape_params):
    dim = HOG.feature_dim + shape_params.feature_dim
    return LinearClassifier(weights=np.zeros((dim, 2), np.float32),
                            intercepts=np.zeros(2, np.float32), class_ids=np.array([1, 2]),
                            hog_params=HOG, shape_params=shape_params,
                            shape_fill=np.zeros(shape_params.feature_dim, np.float32))


def test_describe_uses_the_tight_box_of_each_mask():
    image, depth, mask, K, T = _frame()
    assert mask_box(mask) == (20, 10, 31, 20)  # inclusive pixels, (x, y, w, h)
    model = _model(ShapeParams())
    from_masks = model.describe(image, [mask], depth_m=depth, K=K, T_world_camera=T)
    with_boxes = model.describe(image, [mask], [mask_box(mask)], depth_m=depth, K=K,
                                T_world_camera=T)
    np.testing.assert_array_equal(from_masks, with_boxes)
    np.testing.assert_array_equal(normalise_crop(image, mask=mask, params=HOG),
                                  normalise_crop(image, mask_box(mask), mask, params=HOG))
    np.testing.assert_array_equal(region_points_world(depth, mask, K, T),
                                  region_points_world(depth, mask, K, T, box=mask_box(mask)))


def test_an_empty_mask_is_refused_and_has_no_points():
    image, depth, mask, K, T = _frame()
    empty = np.zeros_like(mask)
    with pytest.raises(ValueError, match='empty'):
        _model(ShapeParams()).describe(image, [mask, empty])
    with pytest.raises(ValueError, match='empty'):
        normalise_crop(image, mask=empty, params=HOG)
    assert region_points_world(depth, empty, K, T).shape == (0, 3)
