"""The seam for new models: the Classifier protocol, LOADERS and load_classifier."""
import inspect
import subprocess
import sys

import numpy as np
import pytest

from tlessbot_ros.core.recognise import (
    FILE_MAGIC,
    LOADERS,
    Classifier,
    LinearClassifier,
    file_magic,
    load_classifier,
    load_linear_classifier,
    read_model_arrays,
)
from tlessbot_ros.data import DEFAULT_CLASSIFIER
from tlessbot_ros.errors import ModelFileError


def test_load_classifier_reads_the_packaged_model_as_linear_classifier_load_does():
    model = load_classifier(DEFAULT_CLASSIFIER)
    direct = LinearClassifier.load(DEFAULT_CLASSIFIER)
    assert isinstance(model, LinearClassifier)
    assert file_magic(DEFAULT_CLASSIFIER) == FILE_MAGIC
    assert LOADERS[FILE_MAGIC] is load_linear_classifier
    features = np.random.default_rng(0).normal(size=(5, direct.feature_dim)).astype(np.float32)
    np.testing.assert_array_equal(model.decision_function(features),
                                  direct.decision_function(features))
    np.testing.assert_array_equal(model.class_ids, direct.class_ids)
    assert model.margin_scale == direct.margin_scale


def test_load_classifier_registers_the_linear_loader_by_itself(tmp_path):
    # A fresh interpreter that imports only load_classifier: nothing has filled LOADERS yet.
    code = ('from tlessbot_ros.core.recognise.model import LOADERS, load_classifier\n'
            'from tlessbot_ros.data import DEFAULT_CLASSIFIER\n'
            'assert not LOADERS, LOADERS\n'
            'print(type(load_classifier(DEFAULT_CLASSIFIER)).__name__)\n')
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == 'LinearClassifier'


def test_another_magic_names_the_known_ones(tmp_path):
    other = tmp_path / 'other.npz'
    np.savez(other, magic=np.array('someone.elses_model'), weights=np.zeros((3, 3)))
    with pytest.raises(ModelFileError, match=FILE_MAGIC) as error:
        load_classifier(other)
    assert 'someone.elses_model' in str(error.value)
    no_magic = tmp_path / 'no_magic.npz'
    np.savez(no_magic, weights=np.zeros((3, 3)))
    with pytest.raises(ModelFileError, match='known'):
        load_classifier(no_magic)
    with pytest.raises(ModelFileError, match='does not exist'):
        load_classifier(tmp_path / 'missing.npz')


def test_read_model_arrays_reads_the_keys_it_is_asked_for(tmp_path):
    path = tmp_path / 'a.npz'
    np.savez(path, magic=np.array('x'), weights=np.ones(3))
    assert set(read_model_arrays(path)) == {'magic', 'weights'}
    assert set(read_model_arrays(path, ('magic', 'absent'))) == {'magic'}
    pickled = tmp_path / 'pickled.npz'
    np.savez(pickled, magic=np.array([{'a': 1}], dtype=object))
    with pytest.raises(ModelFileError, match='not a readable'):
        read_model_arrays(pickled)


def test_linear_classifier_has_every_member_of_the_protocol():
    model = LinearClassifier.load(DEFAULT_CLASSIFIER)
    members = set(Classifier.__annotations__) | {
        name for name, value in vars(Classifier).items()
        if not name.startswith('_') and (callable(value) or isinstance(value, property))}
    assert members >= {'class_ids', 'margin_scale', 'uses_depth', 'describe',
                       'decision_function', 'predict_scores', 'ranked_classes'}
    for name in members:
        assert hasattr(model, name), name
        wanted = getattr(Classifier, name, None)
        if callable(wanted):
            have = inspect.signature(getattr(LinearClassifier, name)).parameters
            assert list(have) == list(inspect.signature(wanted).parameters), name
    assert isinstance(model.uses_depth, bool)
    assert isinstance(model.margin_scale, float)
