"""Top blobs that are fragments of one thin part the side view holds whole.

The top camera, farther away, breaks a thin part up where the side view does not (a dark
plate on dark squares, a plate whose top lies in the depth's noise, :mod:`.thin`): the
calibrated fusion (:mod:`.calibrated_fusion`) would divide the side view's one thin instance
among the top's fragments. So the top blobs over one thin side instance are fragments of that
part and take one id, unless their side pixels differ in colour (a part has one colour, two
thin parts touching need not): in a side blob that is that one instance
(:func:`join_thin_fragments`), and in a piece of a side blob that the fusion keeps apart
from the rest, a plate lying against a taller part (:func:`join_thin_fragments_of_pieces`),
where that piece could be one part: two thin parts of one colour touching make a piece longer
or wider on the table than any part (:func:`~.part_length.fits_a_part`).
"""
from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from tlessbot_ros.core.localise.colour import rgb_to_lab

if TYPE_CHECKING:
    from tlessbot_ros.core.localise.segmentation import Segmentation


def join_thin_fragments(blob: np.ndarray, side: Segmentation, window: tuple[slice, slice],
                        owners: list[int], top_labels: np.ndarray, overlap: np.ndarray,
                        rgb: np.ndarray | None, pred: np.ndarray,
                        floors: np.ndarray) -> list[int]:
    """The owners of a side blob (or of a piece of one; ``blob`` a bool mask of the window) left
    once those that are fragments of one thin part are joined. A side blob that the side
    segmentation keeps as one thin part: the top view, farther away, breaks a thin part up
    where the side view does not (a dark plate on dark squares), so its several owners are
    fragments of that part and take the first one's id in the top labels. But an owner whose
    side pixels (the blob under its prediction; ``rgb`` and ``pred`` cut to the window) differ
    from those of the owner that overlaps the blob most in median colour by more than
    ``floors`` (LAB, any channel; all 0: off) is a part of its own: a part has one colour, two
    touching thin parts need not."""
    own = np.unique(side.labels[window][blob])
    own = own[(own > 0) & (own <= len(side.thin))]
    if own.size != 1 or not side.thin[own - 1].all():
        return owners
    first = max(owners, key=lambda k: int(overlap[k]))
    apart = _other_colours(blob, owners, first, rgb, pred, floors) \
        if rgb is not None and np.any(floors > 0) else []
    fragments = [k for k in owners if k not in apart]
    top_labels[np.isin(top_labels, fragments[1:])] = fragments[0]
    return fragments[:1] + apart


def join_thin_fragments_of_pieces(pieces: list[np.ndarray], side: Segmentation,
                                  window: tuple[slice, slice], owners: list[int],
                                  top_labels: np.ndarray, rgb: np.ndarray | None,
                                  pred: np.ndarray, floors: np.ndarray,
                                  fits_a_part: Callable[[np.ndarray], bool]) -> list[int]:
    """The owners of a side blob that the fusion keeps in ``pieces`` (bool masks of the
    window, the blob divided between the side segmentation's instances), less those that are
    fragments of a thin part: the owners given to one piece (each to the piece it overlaps
    most, as the fusion gives them) are joined as in a blob (:func:`join_thin_fragments`)
    where that piece is one thin side instance and ``fits_a_part`` (of a piece's mask) holds.
    ``pred`` and ``rgb`` are cut to the window."""
    if len(pieces) < 2 or len(owners) < 2:
        return owners
    most = {k: int(np.argmax([np.count_nonzero(p & (pred == k)) for p in pieces]))
            for k in owners}
    for j, piece in enumerate(pieces):
        mine = [k for k in owners if most[k] == j]
        if len(mine) < 2 or not fits_a_part(piece):
            continue
        overlap = np.bincount(pred[piece].ravel(), minlength=max(mine) + 1)
        kept = join_thin_fragments(piece, side, window, mine, top_labels, overlap, rgb, pred,
                                   floors)
        owners = [k for k in owners if k not in mine or k in kept]
    return owners


def _other_colours(blob: np.ndarray, owners: list[int], first: int, rgb: np.ndarray,
                   pred: np.ndarray, floors: np.ndarray) -> list[int]:
    """The owners whose pixels of the blob (under their prediction) differ in median LAB
    colour from those of ``first`` by more than ``floors`` in any channel."""
    lab = rgb_to_lab(rgb)
    under = {k: blob & (pred == k) for k in owners}
    if not under[first].any():
        return []
    reference = np.median(lab[under[first]], axis=0)
    return [k for k in owners if k != first and under[k].any()
            and (np.abs(np.median(lab[under[k]], axis=0) - reference) > floors).any()]


__all__ = ['join_thin_fragments', 'join_thin_fragments_of_pieces']
