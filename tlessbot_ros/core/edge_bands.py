"""A thin band of pixels along a fitted part's edge is that edge, not a part (issue 41).

A stereo camera's smoothed depth spreads a raised part's depth a few pixels onto the table
around it: a band beside the part reads a few millimetres above the table, the localiser
finds it as a region of its own where the colour does not join it to the part, and the pose
stage fits a thin part to it (a strip beside a tube) or puts a second box on the part.
Such a band hugs its part: every pixel of it lies within a few pixels of the part's region.
A part of its own lying beside another shows its own width, however it lies.

Where the band is in the part's own region, the part's fit leaves it unexplained, and the
division after the fit (:func:`~tlessbot_ros.core.two_parts.split_off`) would make it a part
of its own: a piece whose every pixel lies within ``FitParams.edge_band_px`` of the rest of
the region is erased there, not reported (the rest is refitted on its own pixels as after any
division). Where the localiser found it apart, the fragment filter
(:mod:`tlessbot_ros.core.fragments`) drops a piece whose region in its own view lies within
that width of a larger neighbour's region there, when that neighbour is fitted (a pose and a
class); the piece is not reported and its region is erased in every view
(:func:`~tlessbot_ros.core.one_part.join_pieces`).
"""
from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from tlessbot_ros.core.frame import Detection
from tlessbot_ros.core.recognise import UNKNOWN_ID


def band_test(band_px: int, labels: dict[str, np.ndarray]
              ) -> Callable[[Detection, Detection], bool] | None:
    """``band(piece, anchor)`` for the fragment filter: whether ``piece``'s region in its view
    of ``labels`` is a band along fitted ``anchor``'s edge (:func:`is_edge_band`). None when
    ``band_px`` is 0 (off)."""
    if band_px <= 0:
        return None

    def band(piece: Detection, anchor: Detection) -> bool:
        image = labels.get(piece.view)
        return image is not None and anchor.pose is not None and \
            anchor.obj_id != UNKNOWN_ID and \
            is_edge_band(image, piece.instance_id, anchor.instance_id, band_px)
    return band


def is_edge_band(image: np.ndarray, piece: int, anchor: int, band_px: int) -> bool:
    """Whether every pixel of label ``piece`` of ``image`` ((H, W) ints) lies within
    ``band_px`` pixels of label ``anchor``, which holds more pixels (``band_px`` 0: never)."""
    where = np.nonzero(image == piece)
    if not where[0].size or band_px <= 0:
        return False
    y0, x0 = max(int(where[0].min()) - band_px, 0), max(int(where[1].min()) - band_px, 0)
    crop = image[y0:int(where[0].max()) + band_px + 1, x0:int(where[1].max()) + band_px + 1]
    own = crop == piece
    if np.count_nonzero(image == anchor) <= where[0].size or not (crop == anchor).any():
        return False
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * band_px + 1,) * 2)
    near = cv2.dilate((crop == anchor).astype(np.uint8), kernel).astype(bool)
    return not (own & ~near).any()


def without_label(images: dict[str, np.ndarray], instance: int) -> dict[str, np.ndarray]:
    """New label images ((H, W) ints per view, their dtype kept) with ``instance`` erased
    (set to 0); ``images`` is not written into."""
    return {view: np.where(image == instance, 0, image).astype(image.dtype)
            for view, image in images.items()}


__all__ = ['band_test', 'is_edge_band', 'without_label']
