"""Side blobs that one top blob predicts but that the table seen between them keeps apart.

The calibrated fusion gives every side blob that a top blob predicts that blob's id, so two
side blobs with one prediction become one instance: right for a part whose middle a nearer
part hides, or whose middle the cues lost, wrong for two parts that the top view, farther
away, sees as one blob (two brackets a few millimetres apart).

The side depth tells the two apart. A rigid part is connected, so its image is connected
unless something nearer hides part of it; wherever the camera sees the table, the whole line
of sight down to the table is empty, so no part lies there, in front of it or behind it.
Two side blobs are therefore one part only if a path joins them in the image that never
crosses a pixel where the table is seen (it runs over the part itself, the nearer part that
hides it, or pixels without depth that may be either). Where every path between them crosses
the table, they are two parts: the blob that holds most of the prediction keeps its id, the
others get new ones (seen from the side only). Pixels without depth never separate, so dark
parts and holes keep the fusion's answer, and neither do the blobs' own pixels (the depth is
read at the cue scale: a blob's rim may read as the table beside it). Nor does the table
between two thin blobs (:mod:`.thin`): a thin part's top lies within the depth's noise of the
table, so its middle may read as table where the cues lost it (a slotted strip's narrow rim).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from tlessbot_ros.core.localise.segmentation import Segmentation


def apart_by_table(side_labels: np.ndarray, blobs: np.ndarray, pred: np.ndarray,
                   side: Segmentation, next_id: int) -> int:
    """Give new ids (from ``next_id``) to the side blobs of one fused id that the table seen
    in the side view separates from the blob holding most of its prediction (see the module).

    Args:
        side_labels: (H, W) uint16 fused side labels, changed in place.
        blobs: (H, W) int32 connected components (8-connected) of the side foreground.
        pred: (H, W) predicted side regions, ids as in ``side_labels``.
        side: the side segmentation (its ``table_seen``, instances and their thinness).
        next_id: the first free id.

    Returns:
        The next free id.
    """
    if side.table_seen is None:
        return next_id
    on = side_labels > 0
    n_ids, n_blobs = int(side_labels.max()) + 1, int(blobs.max()) + 1
    pairs = np.bincount(side_labels[on].astype(np.int64) * n_blobs + blobs[on],
                        minlength=n_ids * n_blobs).reshape(n_ids, n_blobs)[1:, 1:]
    ids = 1 + np.flatnonzero(np.count_nonzero(pairs, axis=1) > 1)   # carried by 2+ blobs
    if not ids.size:
        return next_id
    # where a path may run without crossing the table: 8-connected, so a wall of table
    # must be closed to separate; over the blobs too (the depth is read at the cue scale,
    # so a blob's rim may read as the table beside it)
    walls = side.table_seen & (side.labels == 0)
    _, reach = cv2.connectedComponents((~walls).view(np.uint8), connectivity=8)
    for k in ids.tolist():
        own = side_labels == k
        carriers = np.unique(blobs[own])
        carriers = carriers[carriers > 0]
        if carriers.size < 2:
            continue
        groups: dict[int, list[int]] = {}
        for b in carriers.tolist():
            here = reach[own & (blobs == b)]
            here = here[here > 0]
            region = int(np.bincount(here).argmax()) if here.size else 0
            groups.setdefault(region, []).append(b)
        if len(groups) < 2 or 0 in groups:   # a blob all on the table: nothing to tell
            continue
        held = {r: int(np.count_nonzero(own & np.isin(blobs, bs) & (pred == k)))
                for r, bs in groups.items()}
        keep = max(held, key=lambda r: held[r])
        thin = {r: _thin(side, own & np.isin(blobs, bs)) for r, bs in groups.items()}
        for region, bs in groups.items():
            if region != keep and not (thin[region] and thin[keep]):
                side_labels[own & np.isin(blobs, bs)] = next_id
                next_id += 1
    return next_id


def _thin(side: Segmentation, mask: np.ndarray) -> bool:
    """Whether every side instance under ``mask`` is a thin part."""
    own = np.unique(side.labels[mask])
    own = own[(own > 0) & (own <= len(side.thin))]
    return bool(own.size) and bool(side.thin[own - 1].all())


__all__ = ['apart_by_table']
