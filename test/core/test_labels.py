import numpy as np
import pytest

from tlessbot_ros.core.common import (
    decode_candidates,
    decode_classes,
    encode_candidates,
    encode_classes,
    instance_masks,
)


def test_round_trip_with_unknown_instance():
    labels = np.array([[0, 1, 1], [2, 2, 3]], np.uint16)
    encoded = encode_classes(labels, {1: 5, 2: 30})
    np.testing.assert_array_equal(encoded, [[0, 5001, 5001], [30002, 30002, 3]])
    instances, classes = decode_classes(encoded)
    np.testing.assert_array_equal(instances, labels)
    assert classes == {1: 5, 2: 30, 3: 0}
    assert set(instance_masks(labels)) == {1, 2, 3}


def test_limits():
    with pytest.raises(ValueError, match='16-bit'):
        encode_classes(np.ones((2, 2), np.uint16), {1: 70})
    with pytest.raises(ValueError, match='instances'):
        encode_classes(np.full((2, 2), 1000, np.uint16), {})


def test_candidates_round_trip_and_channel_zero_is_the_plain_image():
    labels = np.array([[0, 1, 1], [2, 2, 3]], np.uint16)
    candidates = {1: (5, 6, 7), 2: (30,), 3: ()}
    encoded = encode_candidates(labels, candidates, 3)
    assert encoded.shape == (2, 3, 3) and encoded.dtype == np.uint16
    np.testing.assert_array_equal(encoded[..., 0], encode_classes(labels, {1: 5, 2: 30}))
    instances, decoded = decode_candidates(encoded)
    np.testing.assert_array_equal(instances, labels)
    assert decoded == {1: (5, 6, 7), 2: (30,)}       # unknown entries dropped
    plain = encode_candidates(labels, candidates, 1)
    assert plain.shape == labels.shape
    assert decode_candidates(plain)[1] == {1: (5,), 2: (30,)}
    broken = encoded.copy()
    broken[0, 1, 2] = 7002                           # channel 2 names another instance
    with pytest.raises(ValueError, match='channel 2'):
        decode_candidates(broken)
    broken = encoded.copy()
    broken[0, 0, 1] = 5003                           # labelled where channel 0 is background
    with pytest.raises(ValueError, match='channel 1'):
        decode_candidates(broken)


def test_fast_paths_equal_the_whole_image_formulas():
    """encode / decode / label_counts touch only labelled pixels; the result must equal the
    plain whole-image definitions."""
    from tlessbot_ros.core.pipeline import label_counts
    rng = np.random.default_rng(5)
    labels = np.zeros((48, 64), np.uint16)
    for instance in range(1, 6):
        y, x = rng.integers(0, 40), rng.integers(0, 56)
        labels[y:y + 8, x:x + 8] = instance
    candidates = {1: (5, 7), 2: (30,), 4: (12, 13, 14), 9: (2,)}   # 3, 5 unknown; 9 absent
    encoded = encode_candidates(labels, candidates, 3)
    for c in range(3):
        lookup = np.arange(labels.max() + 1)
        for instance, ids in candidates.items():
            if instance < len(lookup) and len(ids) > c:
                lookup[instance] += ids[c] * 1000
        np.testing.assert_array_equal(encoded[..., c], lookup[labels])
    instances, decoded = decode_candidates(encoded)
    np.testing.assert_array_equal(instances, encoded[..., 0] % 1000)
    assert decoded == {1: (5, 7), 2: (30,), 4: (12, 13, 14)}
    np.testing.assert_array_equal(label_counts({'v': labels})['v'], np.bincount(labels.ravel()))
