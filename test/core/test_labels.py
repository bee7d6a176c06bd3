import numpy as np
import pytest

from tlessbot_ros.core.labels import decode_classes, encode_classes, instance_masks


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
