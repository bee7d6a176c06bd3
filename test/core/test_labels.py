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


def _random_labels(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    labels = np.zeros((height, width), np.uint16)
    for instance in rng.permutation(np.arange(1, int(rng.integers(1, 12)) + 1)):
        y, x = rng.integers(-4, height), rng.integers(-4, width)
        h, w = rng.integers(1, 20, 2)
        labels[max(y, 0):y + h, max(x, 0):x + w] = instance
    if rng.random() < 0.3:   # stray pixels, e.g. in the last column
        labels[rng.integers(0, height, 5), rng.integers(0, width, 5)] = rng.integers(1, 70, 5)
    return labels


def test_label_boxes_equal_masks_and_bincount():
    """label_boxes (4 uint16 labels a word for C-contiguous widths that are multiples of 4,
    else pixel by pixel) equals np.bincount and each label's mask_box, on random images of
    every layout and integer type."""
    from tlessbot_ros.core.common import label_boxes, mask_box

    rng = np.random.default_rng(6)
    for trial in range(400):
        labels = _random_labels(rng, int(rng.integers(1, 60)), int(rng.integers(1, 70)))
        kind = trial % 5
        if kind == 1:
            labels = labels.astype(np.int32)
        elif kind == 2:
            labels = labels[:, ::2]                     # not contiguous
        elif kind == 3:
            labels.setflags(write=False)                # a received image: read-only
        elif kind == 4:
            labels = labels > 0
        counts, boxes = label_boxes(labels)
        np.testing.assert_array_equal(counts, np.bincount(labels.ravel().astype(np.int64)))
        for label in range(1, len(counts)):
            want = mask_box(labels == label) if counts[label] else (0, 0, 0, 0)
            assert tuple(boxes[label]) == tuple(want), (trial, label)
        assert tuple(boxes[0]) == (0, 0, 0, 0)


def test_decode_by_words_equals_pixel_by_pixel():
    """decode_candidates' word-at-a-time pass gives what the pixel-by-pixel pass gives:
    instances, first pixels and the first disagreeing channel, on random candidate images
    (also broken ones, and sizes that are not multiples of 4)."""
    from tlessbot_ros.core.common.labels import _decode_kernel

    rng = np.random.default_rng(7)
    for trial in range(400):
        labels = _random_labels(rng, int(rng.integers(1, 40)), int(rng.integers(1, 40)))
        labels[labels >= 1000] = 999
        k = int(rng.integers(1, 5))
        candidates = {int(i): tuple(int(c) for c in rng.integers(0, 66, rng.integers(0, k + 1)))
                      for i in np.unique(labels) if i}
        encoded = encode_candidates(labels, candidates, k).reshape(labels.shape + (k,))
        if trial % 3 == 0 and k > 1:   # a wrong channel somewhere
            y, x = rng.integers(0, labels.shape[0]), rng.integers(0, labels.shape[1])
            encoded[y, x, rng.integers(1, k)] = rng.integers(1, 65535)
        flat = np.ascontiguousarray(encoded.reshape(-1, k))
        by_pixel = _decode_kernel(flat, np.zeros(0, np.uint64))
        if len(flat) % 4 == 0:
            by_word = _decode_kernel(flat, flat.reshape(-1).view(np.uint64))
            assert by_word[2] == by_pixel[2]
            if by_pixel[2] == 0:
                np.testing.assert_array_equal(by_word[0], by_pixel[0])
                np.testing.assert_array_equal(by_word[1], by_pixel[1])
        if by_pixel[2] == 0:
            np.testing.assert_array_equal(decode_candidates(encoded)[0], labels)


def test_encode_candidates_equals_the_lookup_formula():
    """encode_candidates (4 labels a word where the layout allows) equals ``lookup[labels]``
    per channel on random images of any width, contiguous or not."""
    rng = np.random.default_rng(8)
    for trial in range(300):
        labels = _random_labels(rng, int(rng.integers(1, 40)), int(rng.integers(1, 40)))
        if trial % 3 == 1:
            labels = labels[:, ::2]
        k = int(rng.integers(1, 4))
        candidates = {int(i): tuple(int(c) for c in rng.integers(1, 66, rng.integers(0, k + 1)))
                      for i in np.unique(labels) if i}
        encoded = encode_candidates(labels, candidates, k).reshape(labels.shape + (k,))
        for c in range(k):
            lookup = np.arange(labels.max() + 1)
            for instance, ids in candidates.items():
                if len(ids) > c:
                    lookup[instance] += ids[c] * 1000
            np.testing.assert_array_equal(encoded[..., c], lookup[labels])
