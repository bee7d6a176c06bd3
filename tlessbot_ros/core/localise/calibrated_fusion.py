"""The ``'calibrated'`` fusion method (ours, :mod:`.two_view`): each top blob lifted into the
world, extruded down to the table and projected into the side camera, far-to-near, predicts
where each object is visible in the side view; a side blob that holds several predictions is
divided by a watershed seeded with them."""
from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from typing import cast

import cv2
import numpy as np

from tlessbot_ros.core.common import Rig, pixel_counts, transform_points
from tlessbot_ros.core.localise.blob_split import fill_from_nearest, padded_window, pair_roots
from tlessbot_ros.core.localise.fusion_result import (
    FusionParams,
    FusionResult,
    instances_from_labels,
)
from tlessbot_ros.core.localise.gap_colour import apart_by_gap_colour
from tlessbot_ros.core.localise.instances import LIGHTNESS_GROUPS
from tlessbot_ros.core.localise.lightness import top_check
from tlessbot_ros.core.localise.part_length import (
    fits_a_part,
    longer_than_parts,
    table_homography,
)
from tlessbot_ros.core.localise.part_scale import (
    holds_whole_part,
    mask_length_px,
    shared_border_ratio,
)
from tlessbot_ros.core.localise.segmentation import Segmentation
from tlessbot_ros.core.localise.table_gap import apart_by_table
from tlessbot_ros.core.localise.thin_fragments import (
    join_thin_fragments,
    join_thin_fragments_of_pieces,
)


# --------------------------------------------------------------------------- calibrated
def lift_top_blobs(top_labels: np.ndarray, rig: Rig, *, depth_top_m: np.ndarray | None = None,
                   params: FusionParams = FusionParams(),
                   top_name: str = 'top') -> dict[int, np.ndarray]:
    """World points (metres, (N, 3) float64) of each top blob, extruded down to the table.

    With ``depth_top_m`` (NaN read as 0, inf as the largest float, as ``np.nan_to_num``
    does) the blob's valid depth pixels are back-projected (points within
    ``[min_height_m, max_height_m]`` above the table are kept); without it, or when too few
    remain, the pixel rays are cut with the planes z = 0 and z = ``prism_height_m``. Every
    point is then also dropped vertically onto the table (z = 0), since a part standing on
    the table fills the space under its top surface.
    """
    mount = rig[top_name]
    K = mount.intrinsics.K
    step = params.pixel_step
    sub = top_labels[::step, ::step]   # the pixels used, in row-major order
    out: dict[int, np.ndarray] = {}
    n = int(top_labels.max(initial=0))
    ys_all, xs_all = np.nonzero(sub)
    ids_all = sub[ys_all, xs_all]
    ys_all, xs_all = ys_all * step, xs_all * step
    order = np.argsort(ids_all, kind='stable')
    ys_all, xs_all, ids_all = ys_all[order], xs_all[order], ids_all[order]
    bounds = np.searchsorted(ids_all, np.arange(1, n + 2))
    R, t = mount.T_world_camera[:3, :3], mount.T_world_camera[:3, 3]
    for k in range(1, n + 1):
        ys, xs = ys_all[bounds[k - 1]:bounds[k]], xs_all[bounds[k - 1]:bounds[k]]
        if ys.size == 0:
            continue
        pts = np.empty((0, 3))
        if depth_top_m is not None:
            # NaN as 0 and inf as the largest float, read for the blob's pixels only (it was
            # done to the whole image before: the same values)
            z = np.nan_to_num(depth_top_m[ys, xs]).astype(np.float64)
            ok = np.isfinite(z) & (z > 0)
            if ok.any():
                cam = np.column_stack([(xs[ok] - K[0, 2]) * z[ok] / K[0, 0],
                                       (ys[ok] - K[1, 2]) * z[ok] / K[1, 1], z[ok]])
                pts = cam @ R.T + t
                keep = (pts[:, 2] > params.min_height_m) & (pts[:, 2] < params.max_height_m)
                pts = pts[keep]
        if len(pts) < 10:
            rays = np.column_stack([(xs - K[0, 2]) / K[0, 0], (ys - K[1, 2]) / K[1, 1],
                                    np.ones(xs.size)]) @ R.T
            good = rays[:, 2] < -1e-9
            layers = []
            for h in (0.0, params.prism_height_m):
                s = (h - t[2]) / rays[good, 2]
                layers.append(t + rays[good] * s[:, None])
            pts = np.concatenate(layers) if layers else pts
        floor = pts.copy()
        floor[:, 2] = 0.0
        out[k] = np.concatenate([pts, floor])
    return out


def predict_side_regions(points: dict[int, np.ndarray], rig: Rig, *,
                         side_name: str = 'side') -> np.ndarray:
    """Paint the convex hull of each object's projected points into the side image, far first.

    Returns:
        (H, W) uint16 predicted visible id per side pixel (0 = none).
    """
    mount = rig[side_name]
    K, size = mount.intrinsics.K, (mount.intrinsics.height, mount.intrinsics.width)
    pred = np.zeros(size, np.uint16)
    order = []
    for k, pts in points.items():
        cam = transform_points(mount.T_camera_world, pts)
        cam = cam[cam[:, 2] > 0.05]
        if len(cam) < 3:
            continue
        uv = np.column_stack([K[0, 0] * cam[:, 0] / cam[:, 2] + K[0, 2],
                              K[1, 1] * cam[:, 1] / cam[:, 2] + K[1, 2]])
        order.append((float(np.linalg.norm(cam, axis=1).mean()), k, uv))
    for _, k, uv in sorted(order, key=lambda o: -o[0]):
        uv = np.clip(uv, -4 * size[1], 4 * size[1])
        hull = cv2.convexHull(np.round(uv).astype(np.int32))
        cv2.fillConvexPoly(pred, hull, int(k))
    return pred


def _side_prediction(top_labels: np.ndarray, side_shape: tuple[int, ...], rig: Rig,
                     depth_top_m: np.ndarray | None, params: FusionParams, top_name: str,
                     side_name: str) -> tuple[np.ndarray, dict[int, float]]:
    """The (H, W) side view's predicted ids of the top blobs (:func:`predict_side_regions`),
    and the median height (m) of each top blob that the top depth lifts."""
    if depth_top_m is not None and depth_top_m.shape != top_labels.shape:
        raise ValueError(f'depth_top_m shape {depth_top_m.shape} differs from the top labels '
                         f'{top_labels.shape}; align depth to colour first')
    points = lift_top_blobs(top_labels, rig, depth_top_m=depth_top_m, params=params,
                            top_name=top_name)
    pred = predict_side_regions(points, rig, side_name=side_name)
    if pred.shape != side_shape:
        raise ValueError(f'side image {side_shape} differs from the rig side camera '
                         f'{pred.shape}')
    # (the lifted points, then the same dropped onto the table; a blob the depth did not
    # lift is a prism of prism_height_m: no height)
    heights = {}
    for k, pts in points.items():
        z = pts[:len(pts) // 2, 2]
        if depth_top_m is not None and not np.all((z == 0) | (z == params.prism_height_m)):
            heights[k] = float(np.median(z))
    return pred, heights


def calibrated_fusion(top: Segmentation, side: Segmentation, rig: Rig,
                      depth_top_m: np.ndarray | None, side_rgb: np.ndarray | None,
                      params: FusionParams, top_name: str, side_name: str,
                      *, top_rgb: np.ndarray | None = None) -> FusionResult:
    """The ``'calibrated'`` fusion of a top and a side segmentation (``fuse_views``)."""
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    top_labels = top.labels.astype(np.uint16)
    pred, heights = _side_prediction(top_labels, side.labels.shape, rig, depth_top_m, params,
                                     top_name, side_name)
    t1 = time.perf_counter()
    timings['predict'] = (t1 - t0) * 1e3
    n_top = int(top_labels.max(initial=0))
    pred_area = pixel_counts(pred, minlength=n_top + 1)
    side_fg = side.labels > 0
    n_blobs, blobs, stats, _ = cv2.connectedComponentsWithStats(side_fg.astype(np.uint8),
                                                                connectivity=8)
    # Overlap table: rows = side blobs, columns = predicted ids.
    both = side_fg & (pred > 0)
    overlap = np.bincount(blobs[both].astype(np.int64) * (n_top + 1) + pred[both],
                          minlength=n_blobs * (n_top + 1)).reshape(n_blobs, n_top + 1)
    side_labels = np.zeros(side.labels.shape, np.uint16)
    split_ids: set[int] = set()
    next_id = n_top + 1
    fragments: list[int] = []
    kernel = cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (2 * params.seed_erode_px + 1, 2 * params.seed_erode_px + 1))
    for b in range(1, n_blobs):
        owners = _predicted_owners(overlap[b], pred_area, int(stats[b, cv2.CC_STAT_AREA]),
                                   params)
        # Work in the blob's box plus a 1-pixel margin instead of the whole image: a few small
        # parts cover a few % of it.
        x, y, w, h = (int(v) for v in stats[b, :4])
        window = (slice(max(y - 1, 0), y + h + 1), slice(max(x - 1, 0), x + w + 1))
        blob = blobs[window] == b
        out = side_labels[window]
        if len(owners) > 1 and _one_side_instance(blob, side.labels[window]):
            owners = _join_top_fragments(owners, overlap[b], top, top_labels, heights)
        rgb_window = None if side_rgb is None else side_rgb[window]
        floors = params.thin_join_colour_floors * side.colour_floors
        if len(owners) > 1:
            owners = join_thin_fragments(blob, side, window, owners, top_labels, overlap[b],
                                         rgb_window, pred[window], floors)
        if not owners and params.drop_unpredicted:
            continue
        if not owners and n_top > 0 and stats[b, cv2.CC_STAT_AREA] < side.whole_part_px():
            fragments.append(b)   # no part fits it, the top does not see it: placed last
            continue
        if not owners:   # not predicted from the top: the side segmentation's own instances
            next_id = _own_instances(out, blob, side.labels[window], next_id)
        else:
            check = top_check(top_rgb, top_labels, owners, params.lightness_top_ratio)
            pieces = _side_pieces_of_blob(blob, side.labels[window], side, params,
                                          pred[window], owners, check, window) or [blob]
            if params.thin_join_pieces and params.part_footprints_m:
                owners = join_thin_fragments_of_pieces(
                    pieces, side, window, owners, top_labels, rgb_window, pred[window], floors,
                    _fits_a_part(params, rig, side_name, window))
            ids, next_id, divided = _label_pieces(
                pieces, owners, pred[window], rgb_window,
                kernel, next_id, side.whole_part_px(),
                whole_piece_apart=params.whole_pieces_apart)
            out[blob] = ids[blob]
            split_ids.update(divided)
    if params.table_divides and side.table_seen is not None:
        next_id = apart_by_table(side_labels, blobs, pred, side, next_id)
    if params.gap_table_floors > 0 and side_rgb is not None and n_top > 0:
        next_id, divided = apart_by_gap_colour(
            side_labels, top_labels, pred, top, side, side_rgb, next_id,
            floors=params.gap_table_floors * side.colour_floors, band_px=params.gap_band_px,
            min_piece_px=max(side.whole_part_px(), params.min_visible_px),
            side_instances=params.gap_side_instances)
        split_ids.update(divided)
    next_id = _place_fragments(side_labels, blobs, stats, fragments, side, next_id)
    timings['split'] = (time.perf_counter() - t1) * 1e3
    labels = {'top': top_labels, 'side': side_labels}
    return FusionResult(labels=labels, method='calibrated', predicted_side=pred,
                        instances=instances_from_labels(top_labels, side_labels, split_ids),
                        timings_ms=timings)


def _fits_a_part(params: FusionParams, rig: Rig, side_name: str,
                 window: tuple[slice, slice]) -> Callable[[np.ndarray], bool]:
    """Whether a piece (a bool mask of the side ``window``) could be one part on the table
    (:func:`~.part_length.fits_a_part`, ``thin_join_fit``)."""
    return partial(fits_a_part, origin=(window[0].start, window[1].start),
                   H_table_to_image=table_homography(rig, side_name),
                   footprints_m=params.part_footprints_m or (), ratio=params.thin_join_fit)


def _own_instances(out: np.ndarray, blob: np.ndarray, own: np.ndarray, next_id: int) -> int:
    """Give each side instance of ``own`` (labels) in ``blob`` a new id in ``out`` (the
    window's fused labels), from ``next_id``; returns the next free id."""
    for j in np.unique(own[blob]):
        if j:
            out[blob & (own == j)] = next_id
            next_id += 1
    return next_id


def _predicted_owners(overlap: np.ndarray, pred_area: np.ndarray, area: int,
                      params: FusionParams) -> list[int]:
    """The top blobs whose predictions hold a side blob of ``area`` pixels (``overlap``: its
    row of the overlap table, by predicted id; ``pred_area``: each prediction's pixels), or,
    when none does, the one it lies in for ``fragment_fraction`` of it or more."""
    n_top = len(overlap) - 1
    owners = [k for k in range(1, n_top + 1)
              if overlap[k] >= params.min_overlap_px
              and pred_area[k] >= params.min_visible_px
              and overlap[k] >= params.min_overlap_fraction * pred_area[k]]
    if not owners and n_top > 0:
        # A fragment (e.g. of a dark part on a dark square) lying inside one prediction.
        best = int(np.argmax(overlap[1:])) + 1
        if overlap[best] >= params.fragment_fraction * area:
            owners = [best]
    return owners


def _side_pieces_of_blob(blob: np.ndarray, own: np.ndarray, side: Segmentation,
                         params: FusionParams, pred: np.ndarray | None = None,
                         owners: list[int] | None = None,
                         lit_apart: Callable[[], bool] | None = None,
                         window: tuple[slice, slice] | None = None) -> list[np.ndarray]:
    """The pieces of one side blob, seen as one part from the top, that the side view tells
    apart: one bool mask per piece (the blob's pixels of no instance join the nearest piece);
    none unless there are two or more, each of ``min_visible_px`` pixels.

    Two of the side segmentation's instances in the blob stay apart when the depth split
    divided them (different depth groups, ``keep_depth_splits``), or when one is a thin part
    and the other is not (``keep_thin_beside_tall``): a plate or a strip lying against a
    taller part, which the top view, farther away, sees as one blob. With
    ``keep_apart_by_prediction``, so do two instances that the top view's predictions
    ``pred`` give to two of its parts ``owners`` (each instance's most overlapping owner):
    both views have them apart. Every other pair of instances in the blob is one part.
    ``blob``, ``own`` (the side segmentation's labels) and ``pred`` are cut to the blob's
    window. Lightness halves (their groups from ``LIGHTNESS_GROUPS``) count as a depth split
    where ``lit_apart`` (None: always) says the top view shows two lightnesses too. With
    ``apart_longer_than_parts``, two instances that together lie longer on the table than any
    part (:mod:`.part_length`; ``window``: the blob's window in the image) stay apart too,
    and with ``apart_each_whole`` two that could each be a whole part, where one top blob is
    over them all (``owners``; in a pile the top view, farther away, sees touching parts as
    one blob), unless they meet along ``whole_cut_border`` (one part cut across)."""
    ids = np.unique(own[blob])
    ids = ids[(ids > 0) & (ids <= len(side.depth_groups))]
    if ids.size < 2:
        return []
    groups = side.depth_groups[ids - 1]
    lit = groups >= LIGHTNESS_GROUPS
    if lit.any() and lit_apart is not None and not lit_apart():
        groups = np.where(lit, 0, groups)   # one part the top sees alike: a shaded face
    thin = side.thin[ids - 1] if len(side.thin) >= ids.max() else np.zeros(ids.size, bool)
    owner_of = np.zeros(ids.size, int)
    too_long: dict[tuple[int, int], bool] = {}
    one_owner = owners is not None and len(owners) == 1   # (several: their predictions decide)
    origin = (0, 0) if window is None else (window[0].start or 0, window[1].start or 0)
    whole = [one_owner and params.apart_each_whole > 0 and len(side.whole_parts) > 0 and
             holds_whole_part(blob & (own == j), side.whole_parts, params.apart_each_whole)
             for j in ids]

    def by_length(a: int, b: int) -> bool:   # cached: asked again for the same pair
        if not one_owner:
            return False
        if (a, b) not in too_long:
            too_long[a, b] = longer_than_parts(
                side.depth, side.whole_parts, params.apart_longer_than_parts,
                blob & np.isin(own, ids[[a, b]]), origin)
        return too_long[a, b]

    def each_whole(a: int, b: int) -> bool:   # ... unless they meet as one part cut across
        return whole[a] and whole[b] and not (
            params.whole_cut_border > 0 and shared_border_ratio(
                blob & (own == ids[a]), blob & (own == ids[b])) >= params.whole_cut_border)

    def together(a: int, b: int) -> bool:
        by_depth = params.keep_depth_splits and groups[a] > 0 and groups[b] > 0 and \
            groups[a] != groups[b]
        by_height = params.keep_thin_beside_tall and thin[a] != thin[b]
        by_view = owner_of[a] > 0 and owner_of[b] > 0 and owner_of[a] != owner_of[b]
        return not (by_depth or by_height or by_view or by_length(a, b) or each_whole(a, b))

    root_of = pair_roots(ids.size, together)
    if len(set(root_of)) < 2:
        return []
    if params.keep_apart_by_prediction and pred is not None and owners:
        # (a blob of one piece is divided among its owners by the watershed; pieces are not)
        owner_of = _instance_owners(blob, own, ids, pred, owners)
        root_of = pair_roots(ids.size, together)
    roots = sorted(set(root_of))
    piece_of = np.zeros(int(own.max()) + 1, np.int32)
    piece_of[ids] = [roots.index(root_of[a]) + 1 for a in range(ids.size)]
    grouped = np.where(blob, piece_of[own], 0)
    holes = blob & (grouped == 0)
    if holes.any():
        fill_from_nearest(grouped, holes)
    pieces = [grouped == k for k in range(1, len(roots) + 1)]
    if any(np.count_nonzero(p) < params.min_visible_px for p in pieces):
        return []
    return pieces


def _instance_owners(blob: np.ndarray, own: np.ndarray, ids: np.ndarray, pred: np.ndarray,
                     owners: list[int]) -> np.ndarray:
    """(len(ids),) int: for each side instance of ``ids`` in the blob, the owner whose
    prediction covers half of it or more (0: none does)."""
    out = np.zeros(ids.size, int)
    if len(owners) < 2:
        return out
    for a, j in enumerate(ids):
        inside = pred[blob & (own == j)]
        counts = [np.count_nonzero(inside == k) for k in owners]
        if 2 * max(counts) >= inside.size:
            out[a] = owners[int(np.argmax(counts))]
    return out


def _label_pieces(pieces: list[np.ndarray], owners: list[int], pred: np.ndarray,
                  rgb: np.ndarray | None, kernel: np.ndarray, next_id: int,
                  whole_px: float = 0.0, *,
                  whole_piece_apart: bool = False) -> tuple[np.ndarray, int, set[int]]:
    """Ids for the pieces of one side blob (:func:`_side_pieces_of_blob`, or the blob whole)
    held by the top view's predictions ``owners``: each owner goes to the piece it overlaps
    most; a piece with one owner takes its id, a piece with several is divided among them
    (:func:`_divide_among_owners`). A piece with none is a part of its own (a new id, from
    ``next_id``) beside one owner, the fragment of the owner it overlaps most beside several
    or when it is smaller than the smallest whole part, ``whole_px`` (no part fits it). With
    ``whole_piece_apart`` a piece no smaller than that (``whole_px`` > 0: the parts known) is a
    part of its own beside several owners too.

    Returns:
        (the window's int32 ids, the next free id, the owners whose part was divided).
    """
    most = {k: int(np.argmax([np.count_nonzero(p & (pred == k)) for p in pieces]))
            for k in owners}
    ids = np.zeros(pieces[0].shape, np.int32)
    divided: set[int] = set(owners) if len(pieces) > 1 else set()
    for j, piece in enumerate(pieces):
        mine = [k for k in owners if most[k] == j]
        small = np.count_nonzero(piece) < whole_px
        whole = whole_piece_apart and whole_px > 0 and not small   # (0: parts unknown)
        if not mine and (small or (len(owners) > 1 and not whole)):
            # the top view has told the parts of this blob apart: a piece it gives none of
            # them is a fragment of the one it overlaps most
            mine = [max(owners, key=lambda k: np.count_nonzero(piece & (pred == k)))]
        if not mine:
            ids[piece] = next_id
            next_id += 1
        elif len(mine) == 1:
            ids[piece] = mine[0]
        else:
            ids[piece] = _divide_among_owners(piece, pred, mine, rgb, kernel)
            divided.update(mine)
    return ids, next_id, divided


def _one_side_instance(blob: np.ndarray, own: np.ndarray) -> bool:
    """Whether the side segmentation holds a side blob as one instance (``own``: its labels
    in the blob's window)."""
    ids = np.unique(own[blob])
    return int(np.count_nonzero(ids)) == 1


def _join_top_fragments(owners: list[int], overlap: np.ndarray, top: Segmentation,
                        top_labels: np.ndarray, heights: dict[int, float]) -> list[int]:
    """The owners of a side blob that the side segmentation holds as one instance, less the
    top blobs no part fits: one smaller than the smallest whole part of the parts as long as
    it stands high (``top.whole_part_px(height)``, its median height from the top depth)
    beside one that is not is a fragment (of a part the top view, farther away, broke up,
    e.g. at a shaded face) and takes, in the top labels, the id of the other owner that
    overlaps the side blob most; owners none of which is whole are pieces of one part. A thin
    top blob, or one without a height, is never a fragment (a thin part reads small from the
    top), nor is one where the side view, nearer, divides the blob too."""
    if not len(top.whole_parts) or len(top.areas) < max(owners) or \
            len(top.thin) < max(owners):
        return owners
    whole = [k for k in owners if k not in heights or top.thin[k - 1]
             or top.areas[k - 1] >= top.whole_part_px(heights[k])]
    if len(whole) == len(owners):
        return owners
    # none whole: all of them are pieces of one part
    into = max(whole or owners, key=lambda k: int(overlap[k]))
    whole = whole or [into]
    top_labels[np.isin(top_labels, [k for k in owners if k not in whole])] = into
    return whole


def _place_fragments(side_labels: np.ndarray, blobs: np.ndarray, stats: np.ndarray,
                     fragments: list[int], side: Segmentation, next_id: int) -> int:
    """Side blobs that the top does not see and that are smaller than the smallest whole
    part (``side.whole_part_px()``): each joins the labelled side blob nearest to it within the
    side of a square of that area when the two together are no longer than a part can look
    (``side.longest_part_px``: a thin part whose middle the cues lost comes out in pieces),
    else is a part of its own (a new id from ``next_id``). Returns the next free id."""
    reach = max(1, int(np.sqrt(side.whole_part_px())))
    for b in fragments:
        window = padded_window(stats[b, :4], reach, side_labels.shape)
        blob = blobs[window] == b
        near = side_labels[window]
        if near.any():
            dist_to_blob = cv2.distanceTransform((~blob).astype(np.uint8), cv2.DIST_L2,
                                                 3)[near > 0]
            nearest = int(near[near > 0][int(np.argmin(dist_to_blob))])
            if dist_to_blob.min() <= reach and mask_length_px(
                    (side_labels == nearest) | (blobs == b)) <= side.longest_part_px:
                near[blob] = nearest
                continue
        near[blob] = next_id
        next_id += 1
    return next_id


def _divide_among_owners(blob: np.ndarray, pred: np.ndarray, owners: list[int],
                         rgb: np.ndarray | None, kernel: np.ndarray) -> np.ndarray:
    """Ids for the pixels of one side blob held by several predicted objects.

    ``blob``, ``pred`` and ``rgb`` are cut to the blob's box plus a 1-pixel margin (clipped at
    the image border), so the watershed's background marker surrounds the blob."""
    markers = np.zeros(blob.shape, np.int32)
    markers[~blob] = 1
    for k in owners:
        seed = cv2.erode(((pred == k) & blob).astype(np.uint8), kernel).astype(bool)
        if not seed.any():
            seed = (pred == k) & blob
        markers[seed] = k + 1
    if rgb is not None:
        image = np.ascontiguousarray(cv2.GaussianBlur(rgb, (3, 3), 0))
    else:
        image = np.zeros(blob.shape + (3,), np.uint8)
    cv2.watershed(image, markers)
    ids = np.where(blob & (markers > 1), markers - 1, 0)
    # Pixels left (watershed lines) take the nearest assigned id.
    holes = blob & (ids == 0)
    if holes.any() and (ids > 0).any():
        fill_from_nearest(ids, holes)
    return cast(np.ndarray, ids[blob].astype(np.uint16))

__all__ = ['calibrated_fusion', 'lift_top_blobs', 'predict_side_regions']
