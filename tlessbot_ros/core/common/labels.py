"""Label images passed between the nodes (sensor_msgs/Image, 16UC1).

- Instance labels (localiser output): 0 = background, 1..N = instance, and the same instance id
  marks the same physical part in the top and the side view.
- Class-instance labels (classifier output): ``obj_id * 1000 + instance``, the panoptic
  encoding of Cityscapes, so one mono16 image carries both; ``obj_id = 0`` means unknown.
- Class candidates (classifier output with ``class_candidates`` > 1): a 16UC<k> image whose
  channel c holds the class-instance labels of every part's c-th best class; channel 0 alone
  is the plain class-instance image.
"""
from __future__ import annotations

import sys

import numpy as np
from numba import njit

CLASS_STRIDE = 1000
MAX_INSTANCES = CLASS_STRIDE - 1
_LITTLE_ENDIAN = sys.byteorder == 'little'   # a uint64 word's low 16 bits: its first uint16


def encode_classes(instance_labels: np.ndarray, class_of_instance: dict[int, int]) -> np.ndarray:
    """(H, W) uint16 instance labels + {instance: obj_id} -> (H, W) uint16 class-instance labels.

    Instances missing from ``class_of_instance`` keep class 0 (unknown).
    """
    labels = _instance_image(instance_labels)
    lookup = _class_lookup(labels, class_of_instance)
    out = np.zeros(labels.shape, np.uint16)
    labelled = np.flatnonzero(labels != 0)  # parts cover a few % of the image: touch only those
    out.ravel()[labelled] = lookup[labels.ravel()[labelled]]
    return out


def _instance_image(instance_labels: np.ndarray) -> np.ndarray:
    """Checked (H, W) instance labels (at most MAX_INSTANCES)."""
    labels = np.asarray(instance_labels)
    if labels.ndim != 2:
        raise ValueError(f'instance labels must be (H, W), got shape {labels.shape}')
    if labels.size and int(labels.max()) > MAX_INSTANCES:
        raise ValueError(f'at most {MAX_INSTANCES} instances per image, got {int(labels.max())}')
    return labels


def _class_lookup(labels: np.ndarray, class_of_instance: dict[int, int]) -> np.ndarray:
    """uint16 table: instance id -> class-instance label."""
    lookup = np.arange(int(labels.max(initial=0)) + 1, dtype=np.int64)
    for instance, obj_id in class_of_instance.items():
        if not 0 <= obj_id <= 65:
            raise ValueError(f'object id {obj_id} does not fit the 16-bit panoptic encoding')
        if 0 < instance < len(lookup):
            lookup[instance] += obj_id * CLASS_STRIDE
    return lookup.astype(np.uint16)


def decode_classes(class_labels: np.ndarray) -> tuple[np.ndarray, dict[int, int]]:
    """Inverse of :func:`encode_classes`: (instance labels uint16, {instance: obj_id})."""
    class_labels = np.asarray(class_labels)
    instances = (class_labels % CLASS_STRIDE).astype(np.uint16)
    classes = {}
    for value in np.unique(class_labels):
        if value % CLASS_STRIDE:
            classes[int(value % CLASS_STRIDE)] = int(value // CLASS_STRIDE)
    return instances, classes


def encode_candidates(instance_labels: np.ndarray,
                      candidates_of_instance: dict[int, tuple[int, ...]], k: int) -> np.ndarray:
    """(H, W) instance labels + {instance: (obj_id, ...) best first} -> (H, W, k) uint16
    class-instance labels, channel c for the c-th candidate ((H, W) when k is 1). Missing
    candidates are 0 (unknown)."""
    if k < 1:
        raise ValueError(f'need at least one candidate channel, got {k}')
    labels = _instance_image(instance_labels)
    lookups = np.stack([_class_lookup(labels, {
        instance: (tuple(ids)[c] if len(tuple(ids)) > c else 0)
        for instance, ids in candidates_of_instance.items()}) for c in range(k)], axis=-1)
    out = _look_up_labelled(labels, lookups, _words(labels))
    return out[..., 0] if k == 1 else out


def _words(labels: np.ndarray) -> np.ndarray:
    """A C-contiguous uint16 image's pixels as uint64 words, 4 a word (little-endian hosts,
    widths a multiple of 4: a word never spans two rows); else an empty array."""
    if labels.dtype == np.uint16 and labels.ndim == 2 and labels.shape[1] % 4 == 0 and \
            labels.flags.c_contiguous and _LITTLE_ENDIAN:
        return labels.reshape(-1).view(np.uint64)
    return np.zeros(0, np.uint64)


@njit(cache=True, nogil=True)
def _look_up_labelled(labels: np.ndarray, table: np.ndarray, words: np.ndarray) -> np.ndarray:
    """(H, W) labels and an (L, k) uint16 table -> (H, W, k) uint16: ``table[label]`` where
    the label is not 0, else 0. One pass, because the numpy way (flatnonzero, gather, scatter,
    over every channel) walks the frame once per step (docs/bench/code-figures.md). With
    ``words`` (the labels 4 a uint64 word, :func:`_words`) 4 background pixels are passed
    over with one test."""
    height, width = labels.shape
    channels = table.shape[1]
    out = np.zeros((height, width, channels), np.uint16)
    per_row = width // 4
    skip = words.size > 0
    for row in range(height):
        for block in range((width + 3) // 4):
            if skip and words[row * per_row + block] == 0:
                continue
            for col in range(4 * block, min(4 * block + 4, width)):
                label = labels[row, col]
                if label:
                    for c in range(channels):
                        out[row, col, c] = table[label, c]
    return out


def decode_candidates(class_labels: np.ndarray) -> tuple[np.ndarray, dict[int, tuple[int, ...]]]:
    """Inverse of :func:`encode_candidates` (also takes a plain (H, W) class-instance image):
    (instance labels uint16, {instance: (obj_id, ...)} without the unknown entries).

    Raises ValueError when a candidate channel names another instance than channel 0 at some
    pixel."""
    class_labels = np.asarray(class_labels)
    if class_labels.ndim == 2:
        class_labels = class_labels[..., None]
    if class_labels.ndim != 3:
        raise ValueError(f'class labels must be (H, W) or (H, W, k), got {class_labels.shape}')
    flat = np.ascontiguousarray(class_labels.reshape(-1, class_labels.shape[2]),
                                dtype=np.uint16)
    # 4 pixels' k values as k uint64 words (little-endian hosts; else pixel by pixel)
    words = flat.reshape(-1).view(np.uint64) if len(flat) % 4 == 0 and _LITTLE_ENDIAN else \
        np.zeros(0, np.uint64)
    instances, first_pixel, bad_channel = _decode_kernel(flat, words)
    if bad_channel:
        raise ValueError(f'candidate channel {bad_channel} disagrees with channel 0 on the '
                         'instances')
    ids = np.flatnonzero(first_pixel >= 0)
    values = flat[first_pixel[ids]] // CLASS_STRIDE
    return instances.reshape(class_labels.shape[:2]), {
        int(i): tuple(int(v) for v in row if v) for i, row in zip(ids, values) if row.any()}


@njit(cache=True, nogil=True)
def _decode_kernel(flat: np.ndarray, words: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """One pass over (N, k) class-instance labels: (N,) instance ids, the first pixel of every
    instance id (-1 if absent; index 0 unused), and the first channel that disagrees with
    channel 0 on a pixel's instance (0 if none). CLASS_STRIDE is a compile-time constant
    here (a global), so ``%`` compiles to a multiplication, not a division per channel.

    Background (0 in every channel) is most of a frame: with ``words``, ``flat``'s bytes as
    (N k / 4,) uint64 (N a multiple of 4; empty: not used), pixels 4b..4b+3 are words
    kb..kb+k-1, and 4 background pixels are passed over with k tests instead of 4 k
    (docs/bench/stage-cpu.md, docs/bench/code-figures.md).
    """
    n, k = flat.shape
    instances = np.zeros(n, np.uint16)
    first_pixel = np.full(CLASS_STRIDE, -1, np.int64)
    skip = words.size > 0
    for block in range((n + 3) // 4):
        if skip:
            any_set = words[block * k]
            for w in range(block * k + 1, block * k + k):
                any_set |= words[w]
            if any_set == 0:
                continue
        for i in range(4 * block, min(4 * block + 4, n)):
            if flat[i, 0] == 0:   # most pixels: background in every channel
                others = 0
                for c in range(1, k):
                    others |= flat[i, c]
                if others:   # a class but no instance: an error unless the class is 0
                    for c in range(1, k):
                        if flat[i, c] != 0 and flat[i, c] % CLASS_STRIDE != 0:
                            return instances, first_pixel, c
                continue
            instance = flat[i, 0] % CLASS_STRIDE
            for c in range(1, k):
                if flat[i, c] % CLASS_STRIDE != instance:
                    return instances, first_pixel, c
            if instance:
                instances[i] = instance
                if first_pixel[instance] < 0:
                    first_pixel[instance] = i
    return instances, first_pixel, 0


def pixel_counts(labels: np.ndarray, *, minlength: int = 0) -> np.ndarray:
    """``np.bincount(labels.ravel(), minlength=minlength)`` of a label image, reading only the
    labelled pixels (parts cover a few % of an image) for the non-zero bins."""
    flat = np.asarray(labels).ravel()
    labelled = flat[flat != 0]
    counts = np.bincount(labelled, minlength=max(minlength, 1))
    counts[0] = flat.size - labelled.size
    return counts


def label_boxes(labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel count and box of every label of an (H, W) integer label image, in one pass.

    Returns:
        counts: (L,) int64 pixels of each label 0..L-1 (L = the largest label + 1; index 0
            counts the background), as ``np.bincount(labels.ravel())``.
        boxes: (L, 4) int32 (x, y, w, h) of each label's pixels (zeros for a label with none
            and for the background),
            as :func:`~tlessbot_ros.core.common.mask_box` of ``labels == label``: one pass
            instead of one mask and two reductions over the frame per part.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2:
        raise ValueError(f'labels must be (H, W), got shape {labels.shape}')
    if labels.size == 0:
        return np.zeros(1, np.int64), np.zeros((1, 4), np.int32)
    if labels.dtype == bool:
        labels = labels.view(np.uint8)
    if labels.dtype.kind not in 'ui' or (labels.dtype.kind == 'i' and int(labels.min()) < 0):
        raise ValueError(f'labels must be non-negative integers, got {labels.dtype}')
    return _label_boxes(labels, int(labels.max()) + 1, _words(labels))


@njit(cache=True, nogil=True)
def _label_boxes(labels: np.ndarray, size: int, words: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """:func:`label_boxes` of an (H, W) image of labels < ``size``; with ``words`` (the
    labels 4 a uint64 word, :func:`_words`) 4 background pixels are passed over with one
    test, since most of a frame is background (docs/bench/code-figures.md)."""
    height, width = labels.shape
    counts = np.zeros(size, np.int64)
    low = np.full((size, 2), np.iinfo(np.int32).max, np.int32)   # first column, row
    high = np.full((size, 2), -1, np.int32)                       # last column, row
    labelled = 0
    per_row = width // 4
    skip = words.size > 0
    for row in range(height):
        for block in range((width + 3) // 4):
            if skip and words[row * per_row + block] == 0:
                continue
            for col in range(4 * block, min(4 * block + 4, width)):
                label = labels[row, col]
                if label == 0:   # the background is counted at the end; no box
                    continue
                labelled += 1
                counts[label] += 1
                if col < low[label, 0]:
                    low[label, 0] = col
                if col > high[label, 0]:
                    high[label, 0] = col
                if row < low[label, 1]:
                    low[label, 1] = row
                high[label, 1] = row
    counts[0] = height * width - labelled
    boxes = np.zeros((size, 4), np.int32)
    for label in range(1, size):
        if counts[label]:
            boxes[label, 0], boxes[label, 1] = low[label, 0], low[label, 1]
            boxes[label, 2] = high[label, 0] - low[label, 0] + 1
            boxes[label, 3] = high[label, 1] - low[label, 1] + 1
    return counts, boxes


def instance_masks(instance_labels: np.ndarray) -> dict[int, np.ndarray]:
    """{instance id: (H, W) bool mask} of every non-zero label."""
    return {int(i): instance_labels == i for i in np.unique(instance_labels) if i != 0}
