import zipfile

import numpy as np
import pytest

from tlessbot_ros.core.recognise import (
    KINDS,
    UNKNOWN_ID,
    ClassifierParams,
    HogParams,
    LinearClassifier,
    OnlineTrainer,
    train_classifier,
)
from tlessbot_ros.errors import ModelFileError

HOG = HogParams(cell_px=20, bins=2)  # 2x2 blocks x 4 cells x 2 bins = 32 values


def _toy(n_per_class=60, ids=(2, 5, 19), seed=0):
    """Well separated Gaussian blobs in the HOG feature space."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(0.0, 1.0, (len(ids), HOG.feature_dim)) * 3
    x = np.concatenate([c + rng.normal(0, 0.5, (n_per_class, HOG.feature_dim)) for c in centres])
    y = np.repeat(ids, n_per_class)
    return x.astype(np.float32), y


@pytest.mark.parametrize('average', [False, True])
@pytest.mark.parametrize('kind', KINDS)
def test_each_learner_separates_toy_problem(kind, average):
    x, y = _toy()
    model = train_classifier(x, y, hog_params=HOG, params=ClassifierParams(
        kind=kind, epochs=3, average=average), seed=1)
    assert model.kind == kind and model.weights.shape == (HOG.feature_dim, 3)
    test_x, test_y = _toy(n_per_class=30, seed=0)
    rng = np.random.default_rng(9)
    test_x = test_x + rng.normal(0, 0.3, test_x.shape).astype(np.float32)
    pred = model.predict(test_x)
    assert np.mean(pred.class_ids == test_y) > 0.97
    assert set(np.unique(pred.class_ids)) <= {2, 5, 19}
    assert (pred.margins >= 0).all()


def test_numpy_prediction_matches_sklearn():
    from sklearn.linear_model import SGDClassifier

    x, y = _toy()
    trainer = OnlineTrainer(y, params=ClassifierParams(standardise=False), seed=3)
    for _ in range(3):
        trainer.partial_fit(x, y)
    model = trainer.model(HOG)
    assert isinstance(trainer._learner, SGDClassifier)
    np.testing.assert_array_equal(model.predict(x).class_ids, trainer._learner.predict(x))


def test_averaged_weights_differ_from_the_last_ones():
    x, y = _toy()
    weights = {average: train_classifier(x, y, hog_params=HOG, seed=1, params=ClassifierParams(
        epochs=3, average=average)).weights for average in (False, True)}
    assert not np.allclose(weights[False], weights[True])


def test_binary_and_reject_threshold():
    x, y = _toy(ids=(4, 7))
    model = train_classifier(x, y, hog_params=HOG, params=ClassifierParams(kind='pa1'))
    pred = model.predict(x)
    assert np.mean(pred.class_ids == y) > 0.97
    midpoint = (x[y == 4].mean(axis=0) + x[y == 7].mean(axis=0)) / 2
    far = model.predict(x[:1])
    ambiguous = model.predict(midpoint[None])
    assert ambiguous.margins[0] < far.margins[0]
    threshold = float(ambiguous.margins[0] + 1e-3)
    assert model.predict(midpoint[None], reject_margin=threshold).class_ids[0] == UNKNOWN_ID
    assert model.predict(x[:1], reject_margin=threshold).class_ids[0] == 4


def test_deterministic_with_seed():
    x, y = _toy()
    a = train_classifier(x, y, hog_params=HOG, seed=4)
    b = train_classifier(x, y, hog_params=HOG, seed=4)
    np.testing.assert_array_equal(a.weights, b.weights)


def test_npz_round_trip(tmp_path):
    x, y = _toy()
    model = train_classifier(x, y, hog_params=HOG, params=ClassifierParams(reject_margin=0.5))
    path = tmp_path / 'model.npz'
    model.save(path)
    loaded = LinearClassifier.load(path)
    np.testing.assert_array_equal(loaded.weights, model.weights)
    np.testing.assert_array_equal(loaded.class_ids, [2, 5, 19])
    assert loaded.hog_params == HOG and loaded.kind == 'sgd' and loaded.reject_margin == 0.5
    assert loaded.info['samples'] == len(y)
    with np.load(path, allow_pickle=False) as data:
        assert int(data['format_version']) == 3 and str(data['shape_params']) == 'null'
        assert float(data['map_gamma']) == 0.0


def test_margin_scale_is_the_median_training_margin(tmp_path):
    x, y = _toy()
    model = train_classifier(x, y, hog_params=HOG, params=ClassifierParams(epochs=3), seed=1)
    assert model.margin_scale == pytest.approx(float(np.median(model.predict(x).margins)))
    assert model.margin_scale > 0
    assert model.info['train_accuracy'] == pytest.approx(
        float(np.mean(model.predict(x).class_ids == y)), abs=1e-4)
    path = tmp_path / 'm.npz'
    model.save(path)
    assert LinearClassifier.load(path).margin_scale == pytest.approx(model.margin_scale)
    # files from before margin_scale was stored load with 0 (unknown)
    with np.load(path, allow_pickle=False) as data:
        arrays = {k: v for k, v in data.items() if k != 'margin_scale'}
    np.savez(path, **arrays)
    assert LinearClassifier.load(path).margin_scale == 0.0

def test_corrupt_files(tmp_path):
    x, y = _toy()
    good = tmp_path / 'good.npz'
    train_classifier(x, y, hog_params=HOG).save(good)
    with pytest.raises(ModelFileError, match='does not exist'):
        LinearClassifier.load(tmp_path / 'missing.npz')
    garbage = tmp_path / 'garbage.npz'
    garbage.write_bytes(b'not a zip file at all')
    with pytest.raises(ModelFileError, match='not a readable'):
        LinearClassifier.load(garbage)
    truncated = tmp_path / 'truncated.npz'
    truncated.write_bytes(good.read_bytes()[:200])
    with pytest.raises(ModelFileError):
        LinearClassifier.load(truncated)
    other = tmp_path / 'other.npz'
    np.savez(other, weights=np.zeros((3, 3)))
    with pytest.raises(ModelFileError, match='wrong magic'):
        LinearClassifier.load(other)
    pickled = tmp_path / 'pickled.npz'
    np.savez(pickled, magic=np.array([{'a': 1}], dtype=object))
    with pytest.raises(ModelFileError):
        LinearClassifier.load(pickled)
    with np.load(good, allow_pickle=False) as data:
        arrays = dict(data)
    future = tmp_path / 'future.npz'
    np.savez(future, **dict(arrays, format_version=np.array(99)))
    with pytest.raises(ModelFileError, match='version 99'):
        LinearClassifier.load(future)
    broken = tmp_path / 'broken.npz'
    np.savez(broken, **dict(arrays, weights=np.zeros((5, 3), np.float32)))
    with pytest.raises(ModelFileError, match='corrupt'):
        LinearClassifier.load(broken)
    assert zipfile.is_zipfile(good)


def test_errors():
    with pytest.raises(ValueError, match='kind'):
        ClassifierParams(kind='svm')
    x, y = _toy()
    with pytest.raises(ValueError, match='hog_params'):
        train_classifier(x, y)  # 32-dim features, default HOG has 1296
    with pytest.raises(ValueError, match='reserved'):
        OnlineTrainer(np.array([0, 1]))
    trainer = OnlineTrainer(np.array([1, 2]))
    with pytest.raises(ValueError, match='not among'):
        trainer.partial_fit(x[:2], np.array([1, 3]))
    model = train_classifier(x, y, hog_params=HOG)
    with pytest.raises(ValueError, match='expects'):
        model.predict(np.zeros((1, 7), np.float32))


# ------------------------------------------------------------------ metric shape features ("ours")
def _top_down_box(length=0.06, width=0.03, height=0.025, yaw=0.0, size=200):
    """Depth image of a box on the table seen straight down from 1 m, with K and the pose."""
    from tlessbot_ros.core.common import make_transform

    f = 600.0
    K = np.array([[f, 0, size / 2], [0, f, size / 2], [0, 0, 1.0]])
    # camera at z = 1 m looking down: optical z = -world z, optical y = -world y
    R = np.diag([1.0, -1.0, -1.0])
    T_world_camera = make_transform(R, np.array([0.0, 0.0, 1.0]))
    v, u = np.mgrid[0:size, 0:size].astype(float)
    x_w = (u - size / 2) / f * 1.0
    y_w = -(v - size / 2) / f * 1.0
    c, s = np.cos(-yaw), np.sin(-yaw)
    xb, yb = c * x_w - s * y_w, s * x_w + c * y_w
    inside = (np.abs(xb) < length / 2) & (np.abs(yb) < width / 2)
    depth = np.where(inside, 1.0 - height, 1.0).astype(np.float32)
    return depth, inside, K, T_world_camera


def test_shape_features_measure_the_part():
    from tlessbot_ros.core.recognise import (
        ShapeParams,
        region_points_world,
        shape_features,
    )

    params = ShapeParams()
    depth, mask, K, T = _top_down_box()
    points = region_points_world(depth, mask, K, T)
    assert np.allclose(points[:, 2], 0.025, atol=1e-4)
    f = shape_features(points, params=params)
    assert f.shape == (params.feature_dim,) and f.dtype == np.float32
    n = len(params.percentiles)
    np.testing.assert_allclose(f[:n], 2.5, atol=0.01)  # heights in cm
    length, width, ratio, area = f[n + 2 + params.hist_bins:n + 6 + params.hist_bins]
    assert length == pytest.approx(6.0 * 0.96, abs=0.3) and width == pytest.approx(2.9, abs=0.3)
    assert area == pytest.approx(18.0, rel=0.25)
    # yaw-normalised: the same box turned on the table gives (nearly) the same vector
    turned = shape_features(region_points_world(*_top_down_box(yaw=0.7)[:1],
                                                _top_down_box(yaw=0.7)[1], K, T))
    scalars = slice(0, n + 5 + params.hist_bins)  # the grid-counted area varies a little
    np.testing.assert_allclose(turned[scalars], f[scalars], atol=0.4)
    assert turned[n + 5 + params.hist_bins] == pytest.approx(area, rel=0.25)
    # a taller part differs clearly
    tall = shape_features(region_points_world(*_top_down_box(height=0.05)[:2], K, T))
    assert abs(tall[1] - f[1]) > 2.0


def test_shape_features_tolerate_invalid_depth():
    from tlessbot_ros.core.recognise import region_points_world, shape_features

    depth, mask, K, T = _top_down_box()
    rng = np.random.default_rng(0)
    holes = depth.copy()
    holes[rng.random(depth.shape) < 0.3] = 0.0
    holes[rng.random(depth.shape) < 0.1] = np.nan
    bad = mask.copy()
    bad[:, :95] |= True  # table pixels in the region (height 0) are ignored
    a = shape_features(region_points_world(depth, mask, K, T))
    # a region that is 97 % table: keep all its pixels (a 400-point subsample holds ~8 of the part)
    b = shape_features(region_points_world(holes, bad, K, T, max_points=0))
    assert np.all(np.isfinite(b))
    np.testing.assert_allclose(b[:5], a[:5], atol=0.05)
    # box mode (the filled box of the part, table in its corners) with the default subsample
    rows, cols = np.nonzero(mask)
    box = np.zeros_like(mask)
    box[rows.min():rows.max() + 1, cols.min():cols.max() + 1] = True
    c = shape_features(region_points_world(holes, box, K, T))
    np.testing.assert_allclose(c[:5], a[:5], atol=0.05)
    assert shape_features(np.zeros((3, 3))) is None
    assert shape_features(region_points_world(np.zeros_like(depth), mask, K, T)) is None


def test_model_with_shape_features_round_trip(tmp_path):
    from tlessbot_ros.core.recognise import ShapeParams

    shape = ShapeParams()
    x, y = _toy()
    rng = np.random.default_rng(1)
    s = rng.normal(size=(len(y), shape.feature_dim)).astype(np.float32) + y[:, None] * 0.1
    s[:3] = np.nan  # no usable depth for these: filled with the training mean
    model = train_classifier(np.hstack([x, s]), y, hog_params=HOG, shape_params=shape)
    assert model.uses_depth and model.feature_dim == HOG.feature_dim + shape.feature_dim
    assert np.all(np.isfinite(model.shape_fill))
    path = tmp_path / 'ours.npz'
    model.save(path)
    loaded = LinearClassifier.load(path)
    assert loaded.shape_params == shape
    np.testing.assert_array_equal(loaded.shape_fill, model.shape_fill)
    # describe: with depth the shape part is measured, without it is the fill
    depth, mask, K, T = _top_down_box(size=120)
    image = np.where(mask[..., None], 200, 40).astype(np.uint8).repeat(3, axis=2)
    with_depth = loaded.describe(image, [mask], depth_m=depth, K=K, T_world_camera=T)
    without = loaded.describe(image, [mask])
    assert with_depth.shape == without.shape == (1, loaded.feature_dim)
    np.testing.assert_array_equal(without[0, HOG.feature_dim:], loaded.shape_fill)
    assert with_depth[0, HOG.feature_dim] == pytest.approx(2.5, abs=0.05)
    assert loaded.predict(with_depth).class_ids[0] in (2, 5, 19)
    with pytest.raises(ValueError, match='shape_fill'):
        LinearClassifier(model.weights, model.intercepts, model.class_ids, hog_params=HOG,
                         shape_params=shape)


def test_shape_features_batch_matches_single_regions():
    from tlessbot_ros.core.recognise import shape_features, shape_features_batch

    rng = np.random.default_rng(3)
    regions = [rng.normal(size=(50 + 40 * i, 3)) * [0.03, 0.015, 0.02] + [0.3, 0.1, 0.03]
               for i in range(4)]
    regions[1][:7] = np.nan
    regions.insert(2, np.zeros((5, 3)))  # no usable points: a NaN row
    batch = shape_features_batch(regions)
    assert batch.shape == (5, shape_features(regions[0]).shape[0])
    assert np.isnan(batch[2]).all()
    for i in (0, 1, 3, 4):
        np.testing.assert_allclose(batch[i], shape_features(regions[i]), rtol=1e-6)
    # a region's vector does not depend on its neighbours in the batch
    np.testing.assert_allclose(shape_features_batch(regions[::-1])[0], batch[4], rtol=1e-6)
