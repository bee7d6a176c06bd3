"""A posed part's silhouette in a colour image, and how well the image agrees with it.

What the depth of a thin part cannot show, its outline in the colour image does: which corner
is cut, where the holes are. :func:`silhouette` projects a model's surface samples at a pose
into an image window; :func:`agreement` scores it against the window's colour edges (the
share of the outline near a Canny edge: Canny, PAMI 1986; a one-sided chamfer match as in
Barrow et al., IJCAI 1977) and the localiser's label mask; :func:`disputed_votes` compares two
silhouettes where they differ: each disputed pixel looks like the part (its colour nearer the
pixels both silhouettes cover) or like what lies around it (nearer the ring just outside
both), and votes for the silhouette that calls it so.

Images are (H, W, 3) uint8 RGB; windows are (x, y, w, h) pixels; poses ``T_camera_object``
(4, 4) metres, optical frame.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, cast

import cv2
import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics, transform_points

if TYPE_CHECKING:
    import open3d as o3d

# colour samples per class (part, surroundings) for the disputed pixels' nearest neighbour
_SAMPLES = 96
# disputed pixels whose colour is looked at, at most (the votes are scaled to all of them)
_QUERIES = 400


def silhouette(points_o: np.ndarray, T_camera_object: np.ndarray,
               intrinsics: CameraIntrinsics, box: tuple[int, int, int, int],
               spacing_m: float) -> np.ndarray:
    """(h, w) bool silhouette of the model samples ``points_o`` (M, 3) at a pose, in the image
    window ``box`` (x, y, w, h): each sample splatted as a disc as wide as the samples'
    ``spacing_m``."""
    x0, y0, w, h = box
    p = transform_points(T_camera_object, points_o)
    p = p[p[:, 2] > 1e-3]
    mask = np.zeros((h, w), np.uint8)
    if len(p) == 0:
        return mask.astype(bool)
    K = intrinsics.K
    u = np.round(K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2] - x0).astype(int)
    v = np.round(K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2] - y0).astype(int)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    mask[v[inside], u[inside]] = 1
    # a closing fills the gaps between the samples without growing the outline
    radius = max(1, int(np.ceil(0.6 * spacing_m * K[0, 0] / float(np.median(p[:, 2])))))
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * radius + 1, 2 * radius + 1))
    pad = radius + 1
    closed = cv2.morphologyEx(np.pad(mask, pad), cv2.MORPH_CLOSE, kernel)
    return closed[pad:-pad, pad:-pad].astype(bool)


def inside_outline(points_c: np.ndarray, model_c: np.ndarray, spacing_m: float) -> np.ndarray:
    """(N,) bool: which of ``points_c`` (N, 3, camera frame, m) the camera sees through the
    outline of the posed model samples ``model_c`` (M, 3, camera frame), whose neighbours lie
    ``spacing_m`` apart. Both are projected onto cells of viewing directions as wide as a
    sample spacing at the model's median depth (no camera matrix needed: the points came
    through the same pinhole); the model's cells are closed by one cell to fill the gaps
    between its samples, without growing the outline."""
    points_c = np.asarray(points_c, np.float64)
    model_c = np.asarray(model_c, np.float64)
    model_c = model_c[model_c[:, 2] > 1e-6]
    inside = np.zeros(len(points_c), bool)
    if len(model_c) == 0 or spacing_m <= 0:
        return inside
    cell = spacing_m / float(np.median(model_c[:, 2]))
    uv = np.floor(model_c[:, :2] / model_c[:, 2:3] / cell).astype(np.int64)
    low = uv.min(axis=0) - 2
    size = uv.max(axis=0) - low + 3
    marks = np.zeros((int(size[1]), int(size[0])), np.uint8)
    marks[uv[:, 1] - low[1], uv[:, 0] - low[0]] = 1
    grid = cv2.morphologyEx(marks, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8)) > 0
    front = points_c[:, 2] > 1e-6
    q = np.floor(points_c[front, :2] / points_c[front, 2:3] / cell).astype(np.int64) - low
    ok = (q[:, 0] >= 0) & (q[:, 0] < size[0]) & (q[:, 1] >= 0) & (q[:, 1] < size[1])
    hit = np.zeros(len(q), bool)
    hit[ok] = grid[q[ok, 1], q[ok, 0]]
    inside[front] = hit
    return inside


def edge_distance(rgb: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """(h, w) float32 distance (px) to the nearest Canny edge of the colour image in ``box``."""
    x0, y0, w, h = box
    grey = cv2.cvtColor(np.ascontiguousarray(rgb[y0:y0 + h, x0:x0 + w]), cv2.COLOR_RGB2GRAY)
    edges = cv2.Canny(cv2.GaussianBlur(grey, (3, 3), 0), 20, 60)
    return cast(np.ndarray, cv2.distanceTransform((edges == 0).astype(np.uint8), cv2.DIST_L2, 3))


def agreement(mask: np.ndarray, distance: np.ndarray, label: np.ndarray, *,
              edge_px: float, iou_weight: float) -> float:
    """Image agreement in [0, 1] of a silhouette ``mask`` with a window's edge ``distance``
    (:func:`edge_distance`) and the localiser's ``label`` mask (same (h, w) shape)."""
    outline = mask & ~cv2.erode(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    edges = float(np.mean(distance[outline] <= edge_px)) if outline.any() else 0.0
    union = np.count_nonzero(mask | label)
    iou = np.count_nonzero(mask & label) / union if union else 0.0
    return (edges + iou_weight * iou) / (1.0 + iou_weight)




def window(points_o: np.ndarray, poses: Sequence[np.ndarray], intrinsics: CameraIntrinsics,
            *, margin_px: int) -> tuple[int, int, int, int] | None:
    """(x, y, w, h) image window around the projected samples at every pose (None: outside
    the image or behind the camera)."""
    K = intrinsics.K
    us, vs = [], []
    for T in poses:
        p = transform_points(T, points_o)
        p = p[p[:, 2] > 1e-3]
        us.append(K[0, 0] * p[:, 0] / p[:, 2] + K[0, 2])
        vs.append(K[1, 1] * p[:, 1] / p[:, 2] + K[1, 2])
    u, v = np.concatenate(us), np.concatenate(vs)
    if len(u) == 0:
        return None
    x0 = int(max(0, np.floor(u.min()) - margin_px))
    y0 = int(max(0, np.floor(v.min()) - margin_px))
    x1 = int(min(intrinsics.width, np.ceil(u.max()) + margin_px + 1))
    y1 = int(min(intrinsics.height, np.ceil(v.max()) + margin_px + 1))
    return (x0, y0, x1 - x0, y1 - y0) if x1 - x0 > 4 and y1 - y0 > 4 else None


def disputed_votes(mine: np.ndarray, other: np.ndarray, rgb: np.ndarray, *,
                   ring_px: int = 4, seed: int = 0) -> tuple[int, int]:
    """(votes for ``mine``, votes for ``other``): two (h, w) bool silhouettes of one part in
    the (h, w, 3) uint8 window ``rgb``, compared on the pixels where they differ.

    A disputed pixel looks like the part when its colour is nearer the samples of the pixels
    both silhouettes cover (eroded by one pixel) than those of the ring ``ring_px`` wide just
    outside both (distance to the k-th nearest, :func:`_nearest`); it then votes for the
    silhouette that covers it, else for the other one. (0, 0) when they do not differ or a
    sample set is empty.
    """
    both = cv2.erode((mine & other).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    either = (mine | other).astype(np.uint8)
    kernel = np.ones((2 * ring_px + 1, 2 * ring_px + 1), np.uint8)
    ring = cv2.dilate(either, kernel).astype(bool) & ~either.astype(bool)
    disputed = mine ^ other
    if not disputed.any() or not both.any() or not ring.any():
        return 0, 0
    rng = np.random.default_rng(seed)
    colour = rgb.astype(np.float32)
    query, in_mine = colour[disputed], mine[disputed]
    count = len(query)
    if count > _QUERIES:   # an even subset, the votes scaled back to every disputed pixel
        pick = rng.choice(count, _QUERIES, replace=False)
        query, in_mine = query[pick], in_mine[pick]
    looks_part = _nearest(query, _samples(colour, both, rng)) < \
        _nearest(query, _samples(colour, ring, rng))
    for_mine = int(round(count * np.mean(looks_part == in_mine)))
    return for_mine, count - for_mine


def part_likeness(rgb: np.ndarray, part: np.ndarray, surroundings: np.ndarray,
                  where: np.ndarray, *, margin: float = 0.25, seed: int = 0) -> np.ndarray:
    """(h, w) int8 over the (h, w, 3) uint8 window ``rgb``: +1 where a pixel of ``where``
    looks like the part (its colour nearer the samples of the ``part`` pixels than those of
    the ``surroundings``, :func:`_nearest`), -1 where it looks like the surroundings, 0 where
    neither is nearer by ``margin`` of the two distances' sum, outside ``where``, or without
    samples of both."""
    out = np.zeros(rgb.shape[:2], np.int8)
    if not part.any() or not surroundings.any() or not where.any():
        return out
    rng = np.random.default_rng(seed)
    colour = rgb.astype(np.float32)
    # a pixel's likeness depends on its colour alone: each distinct colour once (a window of
    # 8-bit colour holds about one distinct colour in five pixels)
    codes = rgb[where].astype(np.int32) @ np.array([65536, 256, 1], np.int32)
    _, first, back = np.unique(codes, return_index=True, return_inverse=True)
    query = colour[where][first]
    d_part = np.sqrt(np.maximum(_nearest(query, _samples(colour, part, rng)), 0.0))
    d_around = np.sqrt(np.maximum(_nearest(query, _samples(colour, surroundings, rng)), 0.0))
    clear = np.abs(d_around - d_part) > margin * (d_around + d_part)
    out[where] = np.where(clear, np.sign(d_around - d_part), 0).astype(np.int8)[back.ravel()]
    return out


def _samples(colour: np.ndarray, mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """At most ``_SAMPLES`` of the (h, w, 3) float ``colour`` window's pixels under ``mask``,
    drawn at random."""
    pixels = colour[mask]
    chosen: np.ndarray = pixels[rng.choice(len(pixels), _SAMPLES)] \
        if len(pixels) > _SAMPLES else pixels
    return chosen


def _nearest(query: np.ndarray, samples: np.ndarray) -> np.ndarray:
    """(N,) squared distance from each (N, 3) query colour to its k-th nearest sample, k a
    tenth of the samples: robust to the few pixels of the other class that each sample set
    holds (a neighbour in the ring, an edge inside the part)."""
    d = (query * query).sum(axis=1)[:, None] - 2.0 * query @ samples.T + \
        (samples * samples).sum(axis=1)[None, :]
    k = max(1, len(samples) // 10)
    return np.partition(d, k - 1, axis=1)[:, k - 1]


def mesh_silhouette(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                    intrinsics: CameraIntrinsics,
                    box: tuple[int, int, int, int]) -> np.ndarray:
    """(h, w) bool exact silhouette of a mesh at a pose in the window ``box``: the pixel rays
    that hit it (``scene`` an Open3D ``RaycastingScene`` of the mesh in its model frame,
    :func:`~tlessbot_ros.core.common.raycasting_scene`)."""
    _, depth = window_depth(scene, T_camera_object, intrinsics, box)
    return cast(np.ndarray, np.isfinite(depth).reshape(box[3], box[2]))


def window_depth(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                 intrinsics: CameraIntrinsics, box: tuple[int, int, int, int]
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The window ``box``'s pixel rays ((h * w, 3), camera frame, z = 1, row by row) and the
    depth (m, inf where it misses) at which each meets a mesh at a pose."""
    from tlessbot_ros.core.pose.lookalike import depth_along

    x0, y0, w, h = box
    K = intrinsics.K
    v, u = np.mgrid[y0:y0 + h, x0:x0 + w].astype(np.float64)
    rays_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)],
                      axis=-1).reshape(-1, 3)
    return rays_c, depth_along(scene, T_camera_object, rays_c).astype(np.float64)
