"""The views of a frame's label images: which view reads an instance (side first, then top),
each label's pixel count and box, its mask, and the helper thread that runs the second view's
work of a frame."""
from __future__ import annotations

import threading
from collections.abc import Collection
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from tlessbot_ros.core.common import SIDE, TOP, label_boxes, pixel_counts

PREFERRED_VIEWS = (SIDE, TOP)

_SECOND_VIEW: ThreadPoolExecutor | None = None
_SECOND_VIEW_LOCK = threading.Lock()


def second_view_thread() -> ThreadPoolExecutor:
    """One helper thread for the whole process, started on first use and kept (a thread per
    frame would cost its start each time and spread the frames' arrays over malloc arenas).
    Callers submit work and wait for it in the same call."""
    global _SECOND_VIEW
    with _SECOND_VIEW_LOCK:
        if _SECOND_VIEW is None:
            _SECOND_VIEW = ThreadPoolExecutor(1, thread_name_prefix='second_view')
        return _SECOND_VIEW


def view_order(views: Collection[str]) -> list[str]:
    """View names in preference order: side, top, then any other in name order."""
    return [v for v in (*PREFERRED_VIEWS, *sorted(set(views) - set(PREFERRED_VIEWS)))
            if v in views]


def label_counts(labels: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per view, the pixel count of every label (index = label id)."""
    return {view: pixel_counts(image) for view, image in labels.items()}


def label_stats(labels: dict[str, np.ndarray]) -> tuple[dict[str, np.ndarray],
                                                          dict[str, np.ndarray]]:
    """Per view, the pixel count (L,) and the (x, y, w, h) box (L, 4) of every label, from one
    pass over each image (:func:`~tlessbot_ros.core.common.label_boxes`)."""
    stats = {view: label_boxes(image) for view, image in labels.items()}
    return ({view: counts for view, (counts, _) in stats.items()},
            {view: boxes for view, (_, boxes) in stats.items()})


def label_box(boxes: np.ndarray, label: int) -> tuple[int, int, int, int]:
    x, y, w, h = (int(v) for v in boxes[label])
    return x, y, w, h


def mask_in_box(labels: np.ndarray, label: int, box: tuple[int, int, int, int]
                 ) -> np.ndarray:
    """``labels == label`` as an (H, W) bool mask, compared only inside the label's box (the
    rest is False anyway): a part covers a few % of the frame."""
    x, y, w, h = box
    mask = np.zeros(labels.shape, bool)
    mask[y:y + h, x:x + w] = labels[y:y + h, x:x + w] == label
    return mask


def preferred_view(counts: dict[str, np.ndarray], instance_id: int, *,
                   min_px: int) -> str | None:
    """The view in which the pose and class of an instance are read: side first, then top.

    Args:
        counts: per view, the pixel count of every label (:func:`label_counts`).
    """
    for view in view_order(counts):
        if instance_id < len(counts[view]) and counts[view][instance_id] >= min_px:
            return view
    return None


def instance_ids(counts: dict[str, np.ndarray]) -> list[int]:
    """Sorted non-zero labels present in any view, from per-view pixel counts (bincount)."""
    ids: set[int] = set()
    for view_counts in counts.values():
        ids.update(int(v) for v in np.flatnonzero(view_counts) if v != 0)
    return sorted(ids)


__all__ = ['PREFERRED_VIEWS', 'instance_ids', 'label_box', 'label_counts', 'label_stats',
           'mask_in_box', 'preferred_view', 'second_view_thread', 'view_order']
