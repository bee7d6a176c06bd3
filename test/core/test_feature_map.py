import numpy as np
import pytest

from tlessbot_ros.core.recognise import (
    ClassifierParams,
    HogParams,
    LinearClassifier,
    RbfFeatureMap,
    fit_rbf_map,
    train_classifier,
)

HOG = HogParams(cell_px=20, bins=2)  # 32 values


def _rings(n_per_class=150, seed=0):
    """Three concentric shells in the 32-d descriptor space: no hyperplane separates them."""
    rng = np.random.default_rng(seed)
    x, y = [], []
    for obj_id, radius in ((3, 1.0), (8, 2.0), (11, 3.0)):
        direction = rng.normal(size=(n_per_class, HOG.feature_dim))
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        x.append(direction * (radius + rng.normal(0, 0.08, (n_per_class, 1))))
        y.append(np.full(n_per_class, obj_id))
    return np.concatenate(x).astype(np.float32), np.concatenate(y)


def test_nystroem_map_reproduces_the_kernel_on_its_landmarks():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(200, 10)).astype(np.float32)
    mean, scale = x.mean(axis=0), x.std(axis=0)
    fmap, whitening = fit_rbf_map((x - mean) / scale, mean=mean, scale=scale, components=50,
                                  axes=10, gamma=2.0, seed=1)
    assert fmap.input_dim == 10 and fmap.output_dim == 50 and whitening.shape == (50, 50)
    def kernel(a, b):
        za, zb = (a - mean) / scale, (b - mean) / scale
        return np.exp(-2.0 / 10 * ((za[:, None] - zb[None]) ** 2).sum(-1))

    def phi(points):
        return fmap.transform(points) @ whitening

    # the landmarks as descriptors (with every axis kept the projection is invertible)
    at_landmarks = fmap.landmarks @ np.linalg.inv(fmap.projection) + fmap.mean
    np.testing.assert_allclose(phi(at_landmarks) @ phi(at_landmarks).T,
                               kernel(at_landmarks, at_landmarks), atol=1e-3)
    assert np.abs(phi(x) @ phi(x).T - kernel(x, x)).mean() < 0.05
    values = fmap.transform(x)
    assert values.dtype == np.float32 and values.min() > 0 and values.max() <= 1.0


def test_kernel_model_separates_what_a_linear_one_cannot(tmp_path):
    x, y = _rings()
    test_x, test_y = _rings(n_per_class=60, seed=1)
    linear = train_classifier(x, y, hog_params=HOG, seed=0)
    kernel = train_classifier(x, y, hog_params=HOG, seed=0, params=ClassifierParams(
        kernel_components=200, kernel_axes=32, kernel_gamma=3.0, epochs=30))
    assert np.mean(linear.predict(test_x).class_ids == test_y) < 0.6
    assert np.mean(kernel.predict(test_x).class_ids == test_y) > 0.95
    assert kernel.weights.shape == (200, 3) and kernel.feature_map.output_dim == 200
    path = tmp_path / 'kernel.npz'
    kernel.save(path)
    loaded = LinearClassifier.load(path)
    np.testing.assert_allclose(loaded.decision_function(test_x),
                               kernel.decision_function(test_x), rtol=1e-5, atol=1e-5)
    with pytest.raises(ValueError, match='expects 32'):
        loaded.decision_function(test_x[:, :10])


def test_bad_maps_and_settings():
    d, k, m = 6, 3, 4
    good = dict(mean=np.zeros(d, np.float32), projection=np.ones((d, k), np.float32),
                landmarks=np.zeros((m, k), np.float32), gamma=1.0)
    RbfFeatureMap(**good)
    with pytest.raises(ValueError, match='inconsistent'):
        RbfFeatureMap(**dict(good, landmarks=np.zeros((m, k + 1), np.float32)))
    with pytest.raises(ValueError, match='gamma'):
        RbfFeatureMap(**dict(good, gamma=0.0))
    z = np.zeros((10, d), np.float32)
    with pytest.raises(ValueError, match='components'):
        fit_rbf_map(z, mean=z[0], scale=z[0] + 1, components=11, axes=2, gamma=1.0)
    with pytest.raises(ValueError, match='axes'):
        fit_rbf_map(z, mean=z[0], scale=z[0] + 1, components=5, axes=7, gamma=1.0)
    with pytest.raises(ValueError, match='kernel'):
        ClassifierParams(kernel_components=-1)
    x, y = _rings(n_per_class=20)
    with pytest.raises(ValueError, match='standardise'):
        train_classifier(x, y, hog_params=HOG, params=ClassifierParams(
            kernel_components=10, standardise=False))
    model = train_classifier(x, y, hog_params=HOG, params=ClassifierParams(
        kernel_components=10, kernel_axes=4))
    with pytest.raises(ValueError, match='feature map gives'):
        LinearClassifier(model.weights[:5], model.intercepts, model.class_ids, hog_params=HOG,
                         feature_map=model.feature_map)
