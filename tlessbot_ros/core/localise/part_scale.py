"""The smallest part of a parts set as a camera sees it, and the segmentation's sizes that
follow from it in that view.

Two sizes of :class:`~tlessbot_ros.core.localise.SegmentationParams` are in pixels and were
chosen for parts of 3 to 20 cm (T-LESS): the smallest blob kept (``min_area_px``, 80 px) and
the opening that clears thin noise from the candidates (``open_px``, a 3 x 3 cross at the cue
scale: anything narrower than 6 image pixels goes). A part of 8 mm (a nut: about 50 px in
the side camera at 0.64 m, 15 px from the top at 1.1 m) falls under the first; a rod 10 mm
across (10 px wide from the side, 6 px from the top) loses its middle to the second, since
its candidates cover only its middle (its rim reads low in depth and shaded in colour): the
rod comes out in pieces, each a false positive, and the part is missed.

Both follow from the parts and the rig instead: each part's box (its extents, largest
first: a x b x c) rests on its largest face (a x b down, c up) where the camera's optical
axis meets the table; its convex outline projected into the camera is its expected area,
``fx * b / distance`` its expected width. A view keeps blobs down to
``part_area_fraction`` of the smallest part's area (a box's outline is larger than the part,
a part's rim is lost to the cues, and a part may be partly hidden), and opens with at most
the radius whose width is ``part_width_fraction`` of the narrowest part's. Neither is ever
raised above ``min_area_px`` / ``open_px``: a set of parts as large as T-LESS's keeps them.
And a view where the smallest part is no larger than the specks of noise the opening clears
(``(2 open_px + 1)^2`` cue pixels: 36 image pixels) keeps them too: there a part that small
cannot be told from noise by its size (the nut from the top camera: 15 to 25 px), and the
other view finds it.

The same sizes tell a piece from a part (``SegmentationParams.whole_parts``): a blob smaller
than ``part_area_fraction`` of every part at least as long as it looks (and, where its
height is known, as tall as it stands) cannot be a whole part (:func:`whole_part_px`). The
side view's colour split joins such pieces to their neighbours
(:func:`join_pieces_no_part_fits`: a rod with a shaded band), and so does the fusion
(:mod:`.calibrated_fusion`).
"""
from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import cv2
import numpy as np

from tlessbot_ros.core.localise.params import SegmentationParams


def part_view_size(extents_m: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray
                   ) -> tuple[float, float] | None:
    """(area, width) in image pixels of the smallest and of the narrowest part of a set
    seen by one camera (see the module), or None when the camera's optical axis does not
    meet the table (z = 0) in front of it (:func:`part_view_areas`)."""
    seen = part_view_areas(extents_m, K, T_world_camera)
    return None if seen is None else (float(seen[0].min()), seen[1])


def part_view_areas(extents_m: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray
                    ) -> tuple[np.ndarray, float] | None:
    """((N,) each part's expected area, the narrowest part's width) in image pixels seen by
    one camera (see the module), or None when its optical axis does not meet the table.

    Args:
        extents_m: (N, 3) the parts' box extents, metres (any order per row).
        K: (3, 3) the camera's intrinsics.
        T_world_camera: (4, 4) its pose in the table frame (z up, table at z = 0).
    """
    extents = -np.sort(-np.abs(np.asarray(extents_m, np.float64).reshape(-1, 3)), axis=1)
    K = np.asarray(K, np.float64)
    T = np.asarray(T_world_camera, np.float64)
    centre, axis = T[:3, 3], T[:3, 2]
    if extents.size == 0 or axis[2] > -1e-6 or centre[2] <= 0:
        return None
    spot = centre - axis * centre[2] / axis[2]   # the optical axis on the table
    distance = float(np.linalg.norm(spot - centre))
    T_camera_world = np.linalg.inv(T)
    areas = np.zeros((len(extents), 2))
    for i, (a, b, c) in enumerate(extents):
        # either way round on the table
        for j, half in enumerate(((a / 2, b / 2), (b / 2, a / 2))):
            corners = np.array([[sx * half[0], sy * half[1], z] for sx in (-1, 1)
                                for sy in (-1, 1) for z in (0.0, c)]) + [spot[0], spot[1], 0]
            cam = corners @ T_camera_world[:3, :3].T + T_camera_world[:3, 3]
            uv = (cam[:, :2] / cam[:, 2:3]) * [K[0, 0], K[1, 1]]
            areas[i, j] = cv2.contourArea(cv2.convexHull(uv.astype(np.float32)))
    width = 0.5 * (K[0, 0] + K[1, 1]) * float(extents[:, 1].min()) / distance
    return areas.min(axis=1), width


def longest_part_px(extents_m: np.ndarray, K: np.ndarray, T_world_camera: np.ndarray
                    ) -> float | None:
    """The longest (image pixels) any part of a set can look in one camera: its largest
    extent ``a`` at the nearest table point the image's corners and centre see, less ``a``
    (its far end may stand that much nearer), or None when no such ray meets the table."""
    extents = np.abs(np.asarray(extents_m, np.float64).reshape(-1, 3)).max(axis=1)
    K = np.asarray(K, np.float64)
    T = np.asarray(T_world_camera, np.float64)
    cx, cy = K[0, 2], K[1, 2]
    pixels = np.array([[0, 0], [2 * cx, 0], [0, 2 * cy], [2 * cx, 2 * cy], [cx, cy]])
    rays = np.column_stack([(pixels[:, 0] - cx) / K[0, 0], (pixels[:, 1] - cy) / K[1, 1],
                            np.ones(len(pixels))]) @ T[:3, :3].T
    down = rays[:, 2] < -1e-9
    if extents.size == 0 or T[2, 3] <= 0 or not down.any():
        return None
    near = float(np.min(np.linalg.norm(rays[down], axis=1) * T[2, 3] / -rays[down, 2]))
    focal = 0.5 * (K[0, 0] + K[1, 1])
    return float(np.max(focal * extents / np.maximum(near - extents, 0.1 * near)))


def whole_part_px(whole_parts: np.ndarray | tuple[tuple[float, float, float], ...] | None,
                  height_m: float = 0.0, length_px: float = 0.0) -> float:
    """The smallest blob (px) that can be a whole part standing ``height_m`` above the table
    and ``length_px`` long in the image: of the parts that tall and that long (a part stands
    no taller than its largest extent, looks no longer than its longest look; all of them
    when none is), 0 without the parts (``whole_parts``: per part its largest extent in m, its
    smallest whole blob and its longest look in px, ``SegmentationParams.whole_parts``)."""
    table = np.asarray(whole_parts if whole_parts is not None else (), float).reshape(-1, 3)
    if not len(table):
        return 0.0
    fit = table[(table[:, 0] >= height_m) & (table[:, 2] >= length_px)]
    return float((fit if len(fit) else table)[:, 1].min())


def mask_length_px(mask: np.ndarray) -> float:
    """The long side (px) of a mask's smallest rotated rectangle (0 when empty)."""
    points = cv2.findNonZero(np.ascontiguousarray(mask, np.uint8))
    return 0.0 if points is None else float(max(cv2.minAreaRect(points)[1]))


def could_be_whole(piece: np.ndarray, params: SegmentationParams) -> bool:
    """Whether a piece (bool mask) is as large as a whole part as long as it is can be
    (:func:`~tlessbot_ros.core.localise.part_scale.whole_part_px`); True without the parts."""
    return holds_whole_part(piece, params.whole_parts)


def holds_whole_part(piece: np.ndarray,
                     whole_parts: np.ndarray | tuple[tuple[float, float, float], ...] | None,
                     factor: float = 1.0) -> bool:
    """Whether a piece (bool mask) holds ``factor`` times the smallest whole part as long as
    it looks (:func:`whole_part_px` of ``whole_parts``); True without the parts."""
    return cv2.countNonZero(np.ascontiguousarray(piece, np.uint8)) >= \
        factor * whole_part_px(whole_parts, 0.0, mask_length_px(piece))


def shared_border_ratio(a: np.ndarray, b: np.ndarray) -> float:
    """How long two bool masks meet: the pixels of either that touch the other (8-neighbours;
    the larger count) over the square root of the smaller mask's pixels. A cut across one
    part's body runs across the smaller piece's whole width; two parts touching mostly meet
    along a short stretch of their outlines. 0 where either is empty."""
    a8, b8 = np.ascontiguousarray(a, np.uint8), np.ascontiguousarray(b, np.uint8)
    smaller = min(cv2.countNonZero(a8), cv2.countNonZero(b8))
    if smaller == 0:
        return 0.0
    ring = np.ones((3, 3), np.uint8)
    touching = max(cv2.countNonZero(cv2.bitwise_and(a8, cv2.dilate(b8, ring))),
                   cv2.countNonZero(cv2.bitwise_and(b8, cv2.dilate(a8, ring))))
    return float(touching / np.sqrt(smaller))


def join_pieces_no_part_fits(pieces: list[np.ndarray], params: SegmentationParams
                             ) -> list[np.ndarray]:
    """The pieces of one blob (bool masks of one crop), each piece that no part fits whole
    (:func:`could_be_whole`; a part of two colours, a rod with a shaded band) joined to the
    piece it borders most, smallest first. Used in the view split by depth (the side one,
    nearer): from the top a thin part reads small (its rim lost to the cues), and a strip 3 mm
    thick beside a plate would join it."""
    pieces = list(pieces)
    ring = np.ones((3, 3), np.uint8)
    while len(pieces) > 1:
        small = [j for j, p in enumerate(pieces) if not could_be_whole(p, params)]
        if not small:
            break
        j = min(small, key=lambda i: int(np.count_nonzero(pieces[i])))
        border = cv2.dilate(pieces[j].view(np.uint8), ring).astype(bool)
        others = [i for i in range(len(pieces)) if i != j]
        k = max(others, key=lambda i: int(np.count_nonzero(border & pieces[i])))
        pieces[k] = pieces[k] | pieces[j]
        del pieces[j]
    return pieces


def largest_part_px_m2(extents_m: np.ndarray, K: np.ndarray) -> float:
    """The most pixels any part of a set covers in a camera at 1 m (``z_min`` m away: this
    over ``z_min``**2): a part lies inside its box, whose outline seen from any side is
    at most ``sqrt((ab)^2 + (bc)^2 + (ca)^2)`` m^2; at the image's corner a ray meets the
    sensor at the largest angle ``theta`` from the axis, which stretches the outline by at
    most ``1 / cos(theta)``."""
    e = np.abs(np.asarray(extents_m, np.float64).reshape(-1, 3))
    if not len(e):
        return 0.0
    a, b, c = e[:, 0], e[:, 1], e[:, 2]
    outline = float(np.sqrt((a * b) ** 2 + (b * c) ** 2 + (c * a) ** 2).max())
    K = np.asarray(K, np.float64)
    tan_corner = float(np.hypot(K[0, 2] / K[0, 0], K[1, 2] / K[1, 1]))
    return float(K[0, 0] * K[1, 1] * outline * np.sqrt(1.0 + tan_corner ** 2))


def several_parts(blob: np.ndarray, depth_m: np.ndarray,
                  params: SegmentationParams) -> bool:
    """Whether a blob (bool mask; ``depth_m`` its crop's depth, 0 = invalid, at the same
    scale) covers more pixels than any part can at its nearest depth
    (``params.largest_part_px_m2``): several parts. Its rim (the outline is known to one
    pixel) is not counted; False without the parts or depth."""
    if not params.largest_part_px_m2:
        return False
    z = depth_m[blob]
    z = z[z > 0]
    if not z.size:
        return False
    inside = cv2.erode(blob.view(np.uint8), np.ones((3, 3), np.uint8))
    return cv2.countNonZero(inside) > params.largest_part_px_m2 / float(z.min()) ** 2


def view_segmentation(params: SegmentationParams, extents_m: np.ndarray | None,
                      K: np.ndarray, T_world_camera: np.ndarray | None) -> SegmentationParams:
    """``params`` with ``min_area_px`` and ``open_px`` for one view of a parts set (see the
    module): never larger than ``params``' own, ``params`` itself without the parts'
    ``extents_m`` ((N, 3) metres) or the camera's pose."""
    if extents_m is None or T_world_camera is None or \
            (params.part_area_fraction <= 0 and params.part_width_fraction <= 0):
        return params
    return _sized(params, _key(extents_m), _key(K), _key(T_world_camera))


def _key(array: np.ndarray) -> tuple[float, ...]:
    """A hashable copy of an array (its shape is implied by its use), rounded to 1e-6."""
    return tuple(np.round(np.asarray(array, np.float64).ravel(), 6).tolist())


@lru_cache(maxsize=32)
def _sized(params: SegmentationParams, extents: tuple[float, ...], K: tuple[float, ...],
           T: tuple[float, ...]) -> SegmentationParams:
    parts, camera, pose = (np.array(extents).reshape(-1, 3), np.array(K).reshape(3, 3),
                           np.array(T).reshape(4, 4))
    seen = part_view_areas(parts, camera, pose)
    if seen is None:
        return params
    areas, width_px = seen
    area_px = float(areas.min())
    whole = None if params.part_area_fraction <= 0 else tuple(
        (float(np.abs(e).max()), params.part_area_fraction * float(a),
         longest_part_px(e, camera, pose) or 0.0) for e, a in zip(parts, areas))
    largest = largest_part_px_m2(parts, camera)
    if area_px < ((2 * params.open_px + 1) / params.cue_scale) ** 2:
        # no larger than the specks the opening clears: not told from noise
        return replace(params, whole_parts=whole, largest_part_px_m2=largest)
    min_area, open_px = params.min_area_px, params.open_px
    if params.part_area_fraction > 0:
        min_area = min(min_area, max(1, int(params.part_area_fraction * area_px)))
    if params.part_width_fraction > 0:
        # the opening clears what is narrower than 2 r + 1 cue pixels
        widest = params.part_width_fraction * width_px * params.cue_scale
        open_px = min(open_px, max(0, int((widest - 1) // 2)))
    if (min_area, open_px) == (params.min_area_px, params.open_px):
        return replace(params, whole_parts=whole, largest_part_px_m2=largest)
    # the blobs only the parts' sizes admit keep their candidates' extent
    small = params.small_blob_candidates_px or \
        (params.min_area_px if min_area < params.min_area_px else 0)
    return replace(params, min_area_px=min_area, open_px=open_px,
                   small_blob_candidates_px=small, whole_parts=whole,
                   largest_part_px_m2=largest)


__all__ = ['could_be_whole', 'holds_whole_part', 'join_pieces_no_part_fits', 'largest_part_px_m2',
           'longest_part_px', 'mask_length_px', 'part_view_areas', 'part_view_size',
           'several_parts', 'view_segmentation', 'whole_part_px']
