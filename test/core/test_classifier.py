import zipfile

import numpy as np
import pytest

from tlessbot_ros.core.classifier import (
    KINDS,
    UNKNOWN_ID,
    ClassifierParams,
    LinearClassifier,
    OnlineTrainer,
    train_classifier,
)
from tlessbot_ros.core.hog import HogParams
from tlessbot_ros.errors import ModelFileError

HOG = HogParams(cell_px=20, bins=2)  # 2x2 blocks x 4 cells x 2 bins = 32 values


def _toy(n_per_class=60, ids=(2, 5, 19), seed=0):
    """Well separated Gaussian blobs in the HOG feature space."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(0.0, 1.0, (len(ids), HOG.feature_dim)) * 3
    x = np.concatenate([c + rng.normal(0, 0.5, (n_per_class, HOG.feature_dim)) for c in centres])
    y = np.repeat(ids, n_per_class)
    return x.astype(np.float32), y


@pytest.mark.parametrize('kind', KINDS)
def test_each_learner_separates_toy_problem(kind):
    x, y = _toy()
    model = train_classifier(x, y, hog_params=HOG, params=ClassifierParams(kind=kind, epochs=3),
                             seed=1)
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
        assert int(data['format_version']) == 2 and str(data['shape_params']) == 'null'


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
