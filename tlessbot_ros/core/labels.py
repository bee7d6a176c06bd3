"""Label images passed between the nodes (sensor_msgs/Image, 16UC1).

- Instance labels (localiser output): 0 = background, 1..N = instance, and the same instance id
  marks the same physical part in the top and the side view.
- Class-instance labels (classifier output): ``obj_id * 1000 + instance``, the panoptic
  encoding of Cityscapes, so one mono16 image carries both; ``obj_id = 0`` means unknown.
"""
from __future__ import annotations

import numpy as np

CLASS_STRIDE = 1000
MAX_INSTANCES = CLASS_STRIDE - 1


def encode_classes(instance_labels: np.ndarray, class_of_instance: dict[int, int]) -> np.ndarray:
    """(H, W) uint16 instance labels + {instance: obj_id} -> (H, W) uint16 class-instance labels.

    Instances missing from ``class_of_instance`` keep class 0 (unknown).
    """
    labels = np.asarray(instance_labels)
    if labels.ndim != 2:
        raise ValueError(f'instance labels must be (H, W), got shape {labels.shape}')
    if labels.size and int(labels.max()) > MAX_INSTANCES:
        raise ValueError(f'at most {MAX_INSTANCES} instances per image, got {int(labels.max())}')
    lookup = np.arange(int(labels.max(initial=0)) + 1, dtype=np.int64)
    for instance, obj_id in class_of_instance.items():
        if not 0 <= obj_id <= 65:
            raise ValueError(f'object id {obj_id} does not fit the 16-bit panoptic encoding')
        if 0 < instance < len(lookup):
            lookup[instance] += obj_id * CLASS_STRIDE
    return lookup[labels].astype(np.uint16)


def decode_classes(class_labels: np.ndarray) -> tuple[np.ndarray, dict[int, int]]:
    """Inverse of :func:`encode_classes`: (instance labels uint16, {instance: obj_id})."""
    class_labels = np.asarray(class_labels)
    instances = (class_labels % CLASS_STRIDE).astype(np.uint16)
    classes = {}
    for value in np.unique(class_labels):
        if value % CLASS_STRIDE:
            classes[int(value % CLASS_STRIDE)] = int(value // CLASS_STRIDE)
    return instances, classes


def instance_masks(instance_labels: np.ndarray) -> dict[int, np.ndarray]:
    """{instance id: (H, W) bool mask} of every non-zero label."""
    return {int(i): instance_labels == i for i in np.unique(instance_labels) if i != 0}
