"""Dividing one blob that may hold several parts: by depth, by colour, at distance cores.

* **Depth.** The blob's solid pixels (valid depth above the table, off range jumps) in
  several large pieces seed a watershed; two neighbouring pieces stay apart only where the
  depth confirms a seam (table seen between them, or a step).
* **Colour.** A blob of several materials is divided by 2-means on shading-invariant
  chroma (a / L, b / L).
* **Distance cores.** The blob's distance transform, cut at a fraction of its maximum,
  gives cores that seed a watershed (the dividing line runs along the neck).

Every function works on one blob's crop (bool mask with a one-pixel border); the caller,
:mod:`~tlessbot_ros.core.localise.instances`, labels the image.
"""
from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from tlessbot_ros.core.localise.cues import Surfaces, opened
from tlessbot_ros.core.localise.params import SegmentationParams


def watershed_padded(image: np.ndarray, markers: np.ndarray) -> np.ndarray:
    """cv2.watershed without its artefact of marking the image's outer pixels as lines."""
    image = cv2.copyMakeBorder(image, 1, 1, 1, 1, cv2.BORDER_REPLICATE)
    padded = cv2.copyMakeBorder(markers, 1, 1, 1, 1, cv2.BORDER_REPLICATE)
    cv2.watershed(image, padded)
    return padded[1:-1, 1:-1]


def two_means(sample: np.ndarray) -> np.ndarray:
    """(2, D) float32 centres of OpenCV's 2-means (k-means++, seeded: the same answer for the
    same (N, D) float32 ``sample``, a contiguous array of at most ~800 rows)."""
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 10, 0.5)
    cv2.setRNGSeed(0)
    # (OpenCV's stubs want arrays where None has it allocate the output)
    _, _, centres = cv2.kmeans(sample, 2, None, criteria, 1,  # type: ignore[call-overload]
                               cv2.KMEANS_PP_CENTERS)
    return np.asarray(centres, np.float32)


def colour_pieces(blob: np.ndarray, rgb: np.ndarray, params: SegmentationParams,
                   depth: int = 0) -> list[np.ndarray]:
    """Divide a blob made of parts of different materials by 2-means on shading-invariant
    chroma (a / L, b / L); recursive for three or more materials. Returns bool masks."""
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2Lab)
    ab = lab[blob].astype(np.float32)  # (N, 3)
    L = np.maximum(ab[:, 0], np.float32(40.0))
    feats = (ab[:, 1:] - np.float32(128.0)) * (np.float32(100.0) / L)[:, None]
    min_piece = max(params.min_area_px, int(params.colour_split_min_share * len(feats)))
    if len(feats) < 2 * min_piece:
        return [blob]
    # The test and the clustering use at most ~800 pixels; all pixels then take the nearer
    # centre.
    sample = np.ascontiguousarray(feats[::max(1, len(feats) // 800)])
    if sample.std(axis=0).max() < params.colour_split_delta / 4:
        return [blob]
    centres = two_means(sample)
    if float(np.linalg.norm(centres[0] - centres[1])) < params.colour_split_delta:
        return [blob]
    which = (np.sum((feats - centres[1]) ** 2, axis=1)
             < np.sum((feats - centres[0]) ** 2, axis=1)).astype(np.int32)
    cluster = np.zeros(blob.shape, np.int32)
    cluster[blob] = which.ravel() + 1
    seeds = np.zeros(blob.shape, np.int32)
    n_seeds = 0
    for c in (1, 2):
        m = opened((cluster == c), 1).view(np.uint8)
        n, comp, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
        for j in range(1, n):
            if stats[j, cv2.CC_STAT_AREA] >= min_piece:
                n_seeds += 1
                seeds[comp == j] = n_seeds
    if n_seeds < 2:
        return [blob]
    # Every blob pixel joins the nearest seed piece (the seeds lie inside the blob).
    owner = fill_from_nearest(seeds, blob & (seeds == 0))
    pieces = [owner == k for k in range(1, n_seeds + 1)]
    if depth >= 1:
        return pieces
    return [q for p in pieces for q in colour_pieces(p, rgb, params, depth + 1)]


def split_at_distance_cores(blob: np.ndarray, rgb: np.ndarray | None,
                             params: SegmentationParams) -> np.ndarray:
    """Labels 1..k of one blob (a crop with a one-pixel border): its distance transform, cut
    at ``split_core_fraction`` of its maximum, gives k cores that seed a watershed (k = 1: the
    blob stays whole)."""
    dist = cv2.distanceTransform(blob.astype(np.uint8), cv2.DIST_L2, 3)
    top = float(dist.max())
    if top < params.split_min_depth_px:
        return blob.astype(np.int32)
    cores = (dist > params.split_core_fraction * top).astype(np.uint8)
    n, core_labels, stats, _ = cv2.connectedComponentsWithStats(cores, connectivity=8)
    keep = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= params.split_min_core_px]
    if len(keep) < 2:
        return blob.astype(np.int32)
    return divide_by_seeds(blob, core_labels, keep, rgb, dist)


def depth_pieces(blob: np.ndarray, surfaces: Surfaces, rgb: np.ndarray | None,
                  params: SegmentationParams) -> tuple[list[np.ndarray], list[int]]:
    """Bool masks of the parts of one blob (a crop with a one-pixel border) that its depth
    tells apart (``[blob]``: none), and per mask a tie index: pieces that touch only where the
    blob is too narrow to show a seam (a rod entering a handle, two parts meeting at a
    corner) are kept apart but share their tie, which tells the fusion that no seam was
    seen between them (the top view decides).

    The solid pixels' 4-connected pieces of at least ``depth_split_min_px`` seed a
    watershed; two neighbouring pieces stay apart only if the depth confirms a seam between
    them: table seen inside the blob between them (at least ``_SEAM_MIN_PX`` pixels at
    table height, off the blob's rim, which holds some table at every seam's ends), or,
    with ``depth_split_step`` > 0, a step (one side nearer than the other along their
    common border by more than that fraction of the depth). Otherwise they join again: a
    crease or groove of one part breaks its surface too, as do the lines of holes of a dark
    part, but neither shows the table."""
    n, pieces, stats, _ = cv2.connectedComponentsWithStats(
        (surfaces.solid & blob).view(np.uint8), connectivity=4)
    keep = [k for k in range(1, n) if stats[k, cv2.CC_STAT_AREA] >= params.depth_split_min_px]
    if len(keep) < 2:
        return [blob], [0]
    out = divide_by_seeds(blob, pieces, keep, rgb)
    group = list(range(len(keep) + 1))   # union-find over the pieces 1..len(keep)
    tied = list(range(len(keep) + 1))    # ... and with the pieces that touch by a neck

    def root(a: int, of: list[int] = group) -> int:
        while of[a] != a:
            a = of[a]
        return a

    near = [cv2.dilate((out == j).view(np.uint8), _SEAM_KERNEL).view(bool)
            for j in range(len(keep) + 1)]
    # The mask's rim holds some table at every seam's ends: only the inside can show it.
    inside = cv2.erode(blob.view(np.uint8), _SEAM_KERNEL).view(bool)
    for a in range(1, len(keep) + 1):
        for b in range(a + 1, len(keep) + 1):
            seam = near[a] & near[b] & inside
            if not seam.any():
                if (near[a] & (out == b)).any():   # they touch, by a neck only
                    tied[root(b, tied)] = root(a, tied)
                continue
            if root(a) != root(b) and \
                    not _seam_is_real(seam, out == a, out == b, surfaces, params):
                group[root(b)] = root(a)
                tied[root(b, tied)] = root(a, tied)
    roots = sorted({root(j) for j in range(1, len(keep) + 1)})
    if len(roots) < 2:
        return [blob], [0]
    ties = sorted({root(j, tied) for j in range(1, len(keep) + 1)})
    return ([np.isin(out, [j for j in range(1, len(keep) + 1) if root(j) == r]) for r in roots],
            [ties.index(root(r, tied)) for r in roots])


# Two pieces' common border: the pixels within 2 (cue-scale) pixels of both.
_SEAM_KERNEL = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))


def _seam_is_real(seam: np.ndarray, a: np.ndarray, b: np.ndarray, surfaces: Surfaces,
                  params: SegmentationParams) -> bool:
    """Whether the depth confirms the border ``seam`` between pieces ``a`` and ``b`` (bool
    masks of one crop) as the seam of two parts: table seen in it, or a step."""
    # The table along a third of the border between the pieces, not in a hole of one part.
    border = np.count_nonzero(a & cv2.dilate(b.view(np.uint8), _CROSS).view(bool))
    if np.count_nonzero(seam & surfaces.table) >= max(_SEAM_MIN_PX, border / 3):
        return True
    if params.depth_split_step <= 0:
        return False
    depth = surfaces.depth_m
    da, db = depth[seam & a & surfaces.solid], depth[seam & b & surfaces.solid]
    if min(da.size, db.size) < _SEAM_MIN_PX:
        return False
    near_a, near_b = float(np.median(da)), float(np.median(db))
    return abs(near_a - near_b) > params.depth_split_step * min(near_a, near_b)


# Table pixels (cue scale) that show a seam; the depth samples each side needs for a step.
_SEAM_MIN_PX = 3
_CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def divide_by_seeds(blob: np.ndarray, seeds: np.ndarray, keep: list[int],
                     rgb: np.ndarray | None, dist: np.ndarray | None = None) -> np.ndarray:
    """Labels 1..len(keep) of a blob (a crop with a one-pixel border) divided by a
    watershed from the seeds ``seeds == keep[j]`` (label j + 1), on the colour image's
    edges, or without it on the distance map (the dividing line runs along the neck)."""
    markers = np.zeros(blob.shape, np.int32)
    markers[~blob] = 1
    for j, k in enumerate(keep):
        markers[seeds == k] = j + 2
    if rgb is None:
        if dist is None:
            dist = cv2.distanceTransform(blob.astype(np.uint8), cv2.DIST_L2, 3)
        relief = cv2.normalize(-dist, None, 0, 255,  # type: ignore[call-overload]
                               cv2.NORM_MINMAX).astype(np.uint8)
        image = cv2.merge([relief, relief, relief])
    else:
        image = np.ascontiguousarray(cv2.GaussianBlur(rgb, (3, 3), 0))
    markers = watershed_padded(image, markers)
    out = np.where(blob, markers - 1, 0)
    out[out < 0] = 0
    # Watershed-line pixels inside the blob go to their nearest piece.
    holes = blob & (out == 0)
    if holes.any():
        fill_from_nearest(out, holes)
    return out


def fill_from_nearest(labels: np.ndarray, holes: np.ndarray) -> np.ndarray:
    """Give every ``holes`` pixel of an (H, W) integer label image the label of the nearest
    labelled (non-zero) pixel, in place; returns ``labels``."""
    _, nearest = cv2.distanceTransformWithLabels((labels == 0).astype(np.uint8), cv2.DIST_L2, 3,
                                                 labelType=cv2.DIST_LABEL_PIXEL)
    lut = np.zeros(int(nearest.max()) + 1, labels.dtype)
    ys, xs = np.nonzero(labels)
    lut[nearest[ys, xs]] = labels[ys, xs]
    labels[holes] = lut[nearest[holes]]
    return labels


def pair_roots(count: int, together: Callable[[int, int], bool]) -> list[int]:
    """Group ``count`` items by pairs: ``together(a, b)`` (a < b, asked once per pair in
    order) puts a and b in one group. Returns each item's group root, an item index; the
    roots, sorted, number the groups."""
    root = list(range(count))

    def find(a: int) -> int:
        while root[a] != a:
            a = root[a]
        return a

    for a in range(count):
        for b in range(a + 1, count):
            if together(a, b):
                root[find(b)] = find(a)
    return [find(a) for a in range(count)]


def padded_window(box: np.ndarray, pad: int, shape: tuple[int, ...]) -> tuple[slice, slice]:
    """The rows and columns of an (x, y, w, h) box grown by ``pad`` px, within ``shape``."""
    x, y, w, h = (int(v) for v in box)
    return (slice(max(y - pad, 0), min(y + h + pad, shape[0])),
            slice(max(x - pad, 0), min(x + w + pad, shape[1])))
