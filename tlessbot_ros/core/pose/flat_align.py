"""Flat parts' poses compared on the image and the depth, each aligned to them first.

Two poses of a plate a few millimetres thick (the fitted one and its turn, or the part and its
look-alike twin) differ where their holes, slots and cut corners lie: a few pixels each. The
depth fit leaves a thin part a few millimetres off in the table plane (its flat face does not
hold it there), which moves its outline by as many pixels: compared where they stand, the
two poses' outlines dispute more pixels than their holes do, and the vote follows the fit's
error. So each pose is first aligned: its rendering is shifted by whole pixels (as many
either way as the fit's error spans at the part's distance, :func:`shift_px`) to where it agrees
best with the view (a small in-plane search, in the spirit of chamfer matching, Barrow et al.,
IJCAI 1977), and the poses are compared aligned, pixel by pixel, on two cues:

* **height above the table**: the mesh's top surface where a pixel's ray meets the mesh,
  the table (0) where it does not (a hole, beside the outline), against the height the
  measured depth gives (shift-invariant along the table, so a shifted rendering stays
  exact; on a smoothed depth each rendering is smoothed alike, :func:`depth_spread_px`); a
  pixel votes for the pose whose height is nearer by more than ``tolerance_m``.
* **colour**: a pixel that looks like the part (its colour nearer the part's than the
  surroundings'; :func:`~.silhouette.part_likeness`) votes for the pose that covers it, one
  that looks like the surroundings for the pose that leaves it free.

The votes of every view are pooled and a pose replaces another only by a clear margin
(:func:`~.lookalike.clear_margin`).

Poses are ``T_camera_object`` (4, 4) metres in the view's optical frame; windows (x, y, w, h)
pixels; planes (4,) (n·x + d = 0, camera frame, n towards the camera side: the height).
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics

if TYPE_CHECKING:
    import open3d as o3d

    from tlessbot_ros.core.pose.flat import ViewEvidence

# a rendered or measured height this far from the other counts as this far (m): a neighbour
# standing in the window, or a pixel of the table where the mesh stands, weighs no more
_HEIGHT_CAP_M = 0.01


@dataclass(frozen=True)
class AlignedView:
    """What one view shows in the window around a part's poses: ``box`` (x, y, w, h),
    ``height`` (h, w) the measured height above the table (m, NaN without depth),
    ``part_like`` (h, w) int8 colour likeness (+1 part, -1 surroundings, 0 no colour) and
    ``region`` (h, w) bool, the pixels that vote; ``renders`` per pose (hit (H, W) bool,
    height (H, W) m, smoothed as the view's depth: :func:`depth_spread_px`) over the window
    grown by ``pad`` pixels on every side."""

    box: tuple[int, int, int, int]
    height: np.ndarray
    part_like: np.ndarray
    region: np.ndarray
    renders: list[tuple[np.ndarray, np.ndarray]]
    pad: int


def render_heights(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                   intrinsics: CameraIntrinsics, box: tuple[int, int, int, int],
                   plane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(hit (h, w) bool, height (h, w) m): where a mesh at a pose covers the window ``box``
    and the height above the table ``plane`` of what each pixel's ray meets first (the mesh,
    else the table: 0)."""
    from tlessbot_ros.core.pose.silhouette import window_depth

    _, _, w, h = box
    rays_c, depth = window_depth(scene, T_camera_object, intrinsics, box)
    hit = np.isfinite(depth)
    height = np.zeros(len(rays_c))
    height[hit] = (rays_c[hit] * depth[hit, None]) @ plane[:3] + plane[3]
    return hit.reshape(h, w), height.reshape(h, w)


def measured_heights(depth_m: np.ndarray, intrinsics: CameraIntrinsics,
                     box: tuple[int, int, int, int], plane: np.ndarray) -> np.ndarray:
    """(h, w) height (m) above the table ``plane`` of each pixel's measured depth in ``box``
    (NaN where the depth is missing)."""
    x0, y0, w, h = box
    K = intrinsics.K
    z = np.asarray(depth_m[y0:y0 + h, x0:x0 + w], np.float64)
    v, u = np.mgrid[y0:y0 + h, x0:x0 + w].astype(np.float64)
    points = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], axis=-1)
    height = points @ plane[:3] + plane[3]
    return np.where(np.isfinite(z) & (z > 0), height, np.nan)


def table_noise_m(depth_m: np.ndarray, intrinsics: CameraIntrinsics,
                  box: tuple[int, int, int, int], plane: np.ndarray, parts: np.ndarray, *,
                  ring_px: int = 16, blur_px: float = 3.0) -> float:
    """The depth noise (m, a robust sigma) that neighbouring pixels share, measured on the
    bare table around a part: the heights above ``plane`` of the window ``box`` (x, y, w, h)
    grown by ``ring_px``, outside ``box``, off ``parts`` ((H, W) bool, every part's pixels)
    and off anything standing, averaged over a Gaussian of ``blur_px``. A per-pixel noise
    mostly averages out; a smoothed (stereo-like) depth's does not, and it can tilt a small
    part's fit as a whole. 0 with fewer than 50 such pixels."""
    x0, y0, w, h = box
    gx0, gy0 = max(x0 - ring_px, 0), max(y0 - ring_px, 0)
    gx1 = min(x0 + w + ring_px, depth_m.shape[1])
    gy1 = min(y0 + h + ring_px, depth_m.shape[0])
    if gx1 <= gx0 or gy1 <= gy0:
        return 0.0
    height = measured_heights(depth_m, intrinsics, (gx0, gy0, gx1 - gx0, gy1 - gy0), plane)
    table = ~np.asarray(parts[gy0:gy1, gx0:gx1], bool)
    table[max(y0 - gy0, 0):y0 - gy0 + h, max(x0 - gx0, 0):x0 - gx0 + w] = False
    with np.errstate(invalid='ignore'):
        table &= np.abs(height) < _HEIGHT_CAP_M / 2   # NaN (no depth) is no table here
    weight = cv2.GaussianBlur(table.astype(np.float64), (0, 0), blur_px)
    total = cv2.GaussianBlur(np.where(table, height, 0.0), (0, 0), blur_px)
    inner = table & (weight > 0.5)
    if np.count_nonzero(inner) < 50:
        return 0.0
    mean = total[inner] / weight[inner]
    return float(1.4826 * np.median(np.abs(mean - np.median(mean))))


def shifted(array: np.ndarray, pad: int, dx: int, dy: int) -> np.ndarray:
    """The (h, w) window of a map rendered over the window grown by ``pad`` pixels on every
    side, with its content moved by (dx, dy) pixels (|dx|, |dy| <= pad)."""
    h, w = array.shape[0] - 2 * pad, array.shape[1] - 2 * pad
    return array[pad - dy:pad - dy + h, pad - dx:pad - dx + w]


def pixel_votes(view: AlignedView, a: tuple[np.ndarray, np.ndarray],
                b: tuple[np.ndarray, np.ndarray], tolerance_m: float) -> tuple[int, int]:
    """(pixels that pose a explains better, pixels that pose b explains better) of one view,
    both renderings ((hit, height) over the window) already aligned: on the height, by more
    than ``tolerance_m``, and on the colour where one covers a pixel and the other not."""
    region = view.region
    measured = view.height
    has_depth = region & np.isfinite(measured)
    error_a = np.minimum(np.abs(a[1] - measured), _HEIGHT_CAP_M)
    error_b = np.minimum(np.abs(b[1] - measured), _HEIGHT_CAP_M)
    gain = np.where(has_depth, error_b - error_a, 0.0)
    favour = int(np.count_nonzero(gain > tolerance_m))
    against = int(np.count_nonzero(gain < -tolerance_m))
    differ = region & (a[0] != b[0]) & (view.part_like != 0)
    says_a = (view.part_like > 0) == a[0]
    favour += int(np.count_nonzero(differ & says_a))
    against += int(np.count_nonzero(differ & ~says_a))
    return favour, against


def alignment_score(view: AlignedView, hit: np.ndarray, height: np.ndarray,
                    tolerance_m: float) -> float:
    """How well one aligned rendering agrees with a view: the pixels whose height it explains
    within ``tolerance_m`` plus the pixels whose colour likeness it agrees with, minus those
    it contradicts."""
    region = view.region
    with np.errstate(invalid='ignore'):
        explained = np.abs(height - view.height) <= tolerance_m
    colour = np.where(hit, view.part_like, -view.part_like)
    return float(np.count_nonzero(region & explained) + np.sum(colour[region]))


def best_shift(view: AlignedView, k: int, tolerance_m: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Pose ``k``'s rendering shifted to where it agrees best with the view
    (:func:`alignment_score`; no shift on a tie): every shift of at most ``pad`` pixels on a
    grid of 2 pixels, then the 8 shifts around the best of them (:func:`shift_of`)."""
    hit, height = view.renders[k]
    dx, dy = shift_of(view, k, tolerance_m)
    return shifted(hit, view.pad, dx, dy), shifted(height, view.pad, dx, dy)


def shift_of(view: AlignedView, k: int, tolerance_m: float,
             near: tuple[int, int] | None = None) -> tuple[int, int]:
    """(dx, dy) pixels: the shift :func:`best_shift` moves pose ``k``'s rendering by. The
    score is an overlap of a part tens of pixels wide, smooth over a pixel or two, so the
    grid finds its peak's neighbourhood at a quarter of the cost of every shift. Given a
    shift ``near`` which the peak lies beside (that of a pose a little way off), the best of
    its 8 neighbours is taken while it scores better (a climb of a few pixels, no grid)."""
    hit, height = view.renders[k]
    pad = view.pad

    def score(shift: tuple[int, int]) -> float:
        return alignment_score(view, shifted(hit, pad, *shift), shifted(height, pad, *shift),
                               tolerance_m)

    if near is not None:
        return _climb(score, near, pad)
    best, best_score = (0, 0), score((0, 0))
    grid = range(-(pad // 2) * 2, pad + 1, 2)
    coarse = [(dx, dy) for dy in grid for dx in grid]
    for shifts in (coarse, None):
        if shifts is None:   # the 8 neighbours of the grid's best
            shifts = [(best[0] + dx, best[1] + dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                      if max(abs(best[0] + dx), abs(best[1] + dy)) <= pad]
        for shift in shifts:
            if shift != (0, 0) and (value := score(shift)) > best_score:
                best, best_score = shift, value
    return best


def _climb(score: Callable[[tuple[int, int]], float], start: tuple[int, int], pad: int
           ) -> tuple[int, int]:
    """The shift reached from ``start`` by steps to the best-scoring of the 8 neighbours
    (within ``pad`` either way) while it scores better than where the climb stands."""
    best, best_score = start, score(start)
    while True:
        around = [(best[0] + dx, best[1] + dy) for dy in (-1, 0, 1) for dx in (-1, 0, 1)
                  if (dx or dy) and max(abs(best[0] + dx), abs(best[1] + dy)) <= pad]
        value, shift = max(((score(a), a) for a in around), default=(best_score, best))
        if value <= best_score:
            return best
        best, best_score = shift, value


def pooled_votes(views: Sequence[AlignedView], count: int, tolerance_m: float
                 ) -> np.ndarray:
    """(count, count) int: [i, j] the pixels of every view that pose i explains better than
    pose j (:func:`pixel_votes`), each pose aligned on its own (:func:`best_shift`)."""
    votes = np.zeros((count, count), np.int64)
    for view in views:
        aligned = [best_shift(view, k, tolerance_m) for k in range(count)]
        for i in range(count):
            for j in range(i + 1, count):
                votes[i, j], votes[j, i] = np.add(
                    (votes[i, j], votes[j, i]),
                    pixel_votes(view, aligned[i], aligned[j], tolerance_m))
    return votes


def round_robin(votes: np.ndarray) -> int:
    """The pose that wins most of its duels (``votes`` [i, j]: pixels for i against j; ties
    by the total surplus, then the lowest index)."""
    net = votes - votes.T
    wins = np.count_nonzero(net > 0, axis=1)
    order = np.lexsort((np.arange(len(wins)), -net.sum(axis=1), -wins))
    return int(order[0])


def undominated(votes: np.ndarray, min_z: float) -> list[int]:
    """The poses that no other pose beats by a clear margin (``votes`` [i, j]: pixels for i
    against j; :func:`~.lookalike.clear_margin` at ``min_z``)."""
    from tlessbot_ros.core.pose.lookalike import clear_margin

    count = len(votes)
    return [i for i in range(count)
            if not any(clear_margin(int(votes[j, i]), int(votes[i, j]), min_z)
                       for j in range(count) if j != i)]


def aligned_view(renderers: Sequence[tuple[o3d.t.geometry.RaycastingScene, np.ndarray]],
                 box: tuple[int, int, int, int], pad: int, intrinsics: CameraIntrinsics,
                 plane: np.ndarray, *, rgb: np.ndarray | None, depth_m: np.ndarray | None,
                 others: np.ndarray | None, tolerance_m: float) -> AlignedView:
    """The :class:`AlignedView` of poses ((mesh scene, ``T_camera_object``) each) in the
    window ``box`` of one view: its colour (or None), depth (or None), the table ``plane``
    and the pixels the localiser gave other parts (``others`` (H, W) bool, or None)."""
    x0, y0, w, h = box
    grown = (x0 - pad, y0 - pad, w + 2 * pad, h + 2 * pad)
    renders = [render_heights(scene, T, intrinsics, grown, plane) for scene, T in renderers]
    height = measured_heights(depth_m, intrinsics, box, plane) if depth_m is not None \
        else np.full((h, w), np.nan)
    cut = None if others is None else np.asarray(others[y0:y0 + h, x0:x0 + w], bool)
    region = voting_region(renders, pad, cut)
    part_like = np.zeros((h, w), np.int8)
    if rgb is not None:
        from tlessbot_ros.core.pose.silhouette import part_likeness

        hits = [shifted(hit, pad, 0, 0) for hit, _ in renders]
        inside = cv2.erode(np.logical_and.reduce(hits).astype(np.uint8),
                           np.ones((5, 5), np.uint8)).astype(bool)
        outer = cv2.dilate(np.logical_or.reduce(hits).astype(np.uint8),
                           np.ones((2 * pad + 13, 2 * pad + 13), np.uint8)).astype(bool)
        with np.errstate(invalid='ignore'):
            table = ~(height > tolerance_m)   # NaN (no depth) counts as table here
            raised = ~(height < tolerance_m)
        ring = outer & ~region & table & (cut is None or ~cut)
        window_rgb = np.asarray(rgb[y0:y0 + h, x0:x0 + w])
        part_like = part_likeness(window_rgb, inside & raised, ring, region)
    view = AlignedView(box, height, part_like, region, renders, pad)
    if depth_m is None or not renders:
        return view
    # a smoothed depth (a RealSense's) spreads a thin part's edges and fills its small holes:
    # each pose's heights are compared smoothed alike, so neither votes on them; the spread is
    # measured where the first pose aligns (a misplaced outline would pass for a spread), and
    # only where that pose, blurred, meets the depth within the votes' tolerance: a blur
    # lowers any misplaced rendering's error (a fit tens of degrees off), a spread it is not
    sigma = depth_spread_px(height, renders[0], pad, region,
                            shift_of(view, 0, tolerance_m), max_error_m=tolerance_m)
    if sigma <= 0:
        return view
    return AlignedView(box, height, part_like, region,
                       [(hit, cv2.GaussianBlur(rendered, (0, 0), sigma))
                        for hit, rendered in renders], pad)


# the spreads (Gaussian sigma, pixels) tried for the depth's smoothing: none (a per-pixel
# depth), up to a RealSense's ~10 px bilateral window (docs/bench/smoothed-depth-flat.md)
_SPREADS_PX = (0.0, 1.0, 2.0, 3.0, 4.0, 5.0)


def depth_spread_px(measured: np.ndarray, render: tuple[np.ndarray, np.ndarray], pad: int,
                    region: np.ndarray, shift: tuple[int, int] = (0, 0), *,
                    max_error_m: float = np.inf) -> float:
    """The spread (Gaussian sigma, pixels) over which the view's depth is smoothed, measured
    on the part: of ``_SPREADS_PX``, the one whose blur of a pose's rendered heights (``render``
    over the window grown by ``pad``, moved by ``shift`` (dx, dy) pixels) meets the measured
    ``(h, w)`` heights in ``region`` with the least mean absolute error (0 with fewer than 50
    such pixels, and 0 where that least error exceeds ``max_error_m``: the pose misses the
    depth, and what a blur gains on it is the pose's error)."""
    has_depth = region & np.isfinite(measured)
    if np.count_nonzero(has_depth) < 50:
        return 0.0
    best, best_error = 0.0, np.inf
    for sigma in _SPREADS_PX:
        heights = cv2.GaussianBlur(render[1], (0, 0), sigma) if sigma > 0 else render[1]
        error = float(np.mean(np.abs(shifted(heights, pad, *shift) - measured)[has_depth]))
        if error < best_error - 1e-5:   # a blur must explain the depth better, not as well
            best, best_error = sigma, error
    return best if best_error <= max_error_m else 0.0


def view_votes(scenes: Sequence[o3d.t.geometry.RaycastingScene], poses: Sequence[np.ndarray],
               points_o: np.ndarray, views: Sequence[ViewEvidence], *, align_at_1m_m: float,
               tolerance_m: float) -> np.ndarray:
    """(K, K) :func:`pooled_votes` of K poses (pose k of the mesh ``scenes[k]``, in the fitted
    view's frame; ``points_o`` the model samples that bound them) over every view with a
    table plane and colour or depth, each rendering aligned by shifts that cover the fit's
    error in the table plane (``align_at_1m_m`` at 1 m, :func:`shift_px`)."""
    from tlessbot_ros.core.pose.silhouette import window

    aligned = []
    for view in views:
        if view.plane is None or (view.rgb is None and view.depth_m is None):
            continue
        T = [view.T_view_fit @ np.asarray(T_k, np.float64) for T_k in poses]
        pad = shift_px(view.intrinsics, points_o, T[0], align_at_1m_m)
        box = window(points_o, T, view.intrinsics, margin_px=pad + 4)
        if box is None:
            continue
        aligned.append(aligned_view(list(zip(scenes, T)), box, pad, view.intrinsics,
                                    view.plane, rgb=view.rgb, depth_m=view.depth_m,
                                    others=view.others, tolerance_m=tolerance_m))
    return pooled_votes(aligned, len(poses), tolerance_m)


def pose_spread_px(scene: o3d.t.geometry.RaycastingScene, T_camera_object: np.ndarray,
                   points_o: np.ndarray, views: Sequence[ViewEvidence], *, align_at_1m_m: float,
                   tolerance_m: float) -> float:
    """How far the depth is smoothed where a pose (of the mesh ``scene``, in the fitted view's
    frame; ``points_o`` its model samples) lies: the largest :func:`depth_spread_px` over the
    views with depth and a table plane, the pose aligned as it votes, however far it misses
    the depth (0: per-pixel everywhere)."""
    from tlessbot_ros.core.pose.silhouette import window

    spread = 0.0
    for view in views:
        if view.plane is None or view.depth_m is None:
            continue
        T = view.T_view_fit @ np.asarray(T_camera_object, np.float64)
        pad = shift_px(view.intrinsics, points_o, T, align_at_1m_m)
        box = window(points_o, [T], view.intrinsics, margin_px=pad + 4)
        if box is None:
            continue
        x0, y0, w, h = box
        render = render_heights(scene, T, view.intrinsics,
                                (x0 - pad, y0 - pad, w + 2 * pad, h + 2 * pad), view.plane)
        height = measured_heights(view.depth_m, view.intrinsics, box, view.plane)
        cut = None if view.others is None else np.asarray(view.others[y0:y0 + h, x0:x0 + w], bool)
        region = voting_region([render], pad, cut)
        plain = AlignedView(box, height, np.zeros((h, w), np.int8), region, [render], pad)
        spread = max(spread, depth_spread_px(height, render, pad, region,
                                             shift_of(plain, 0, tolerance_m)))
    return spread


def shift_px(intrinsics: CameraIntrinsics, points_o: np.ndarray, T_camera_object: np.ndarray,
             align_at_1m_m: float) -> int:
    """The whole pixels that the fit's error in the table plane spans at the distance z of a
    part at a pose (the median depth of its model samples ``points_o``): how far the aligned
    votes shift each rendering. The error grows as the depth's noise, with z² (a stereo
    camera's disparity error; ``align_at_1m_m`` is its size at 1 m), and a length at z spans
    f / z pixels: f · align_at_1m_m · z in all."""
    depth = float(np.median(np.asarray(points_o, np.float64) @ T_camera_object[2, :3]
                            + T_camera_object[2, 3]))
    if align_at_1m_m <= 0 or depth <= 0:
        return 0
    return int(np.ceil(intrinsics.K[0, 0] * align_at_1m_m * depth))


def voting_region(renders: Sequence[tuple[np.ndarray, np.ndarray]], pad: int,
                  others: np.ndarray | None) -> np.ndarray:
    """(h, w) bool: the pixels within ``pad`` + 2 pixels of any pose's rendering (each over
    the window grown by ``pad``), less those the localiser gave another part (``others``)."""
    union = np.zeros_like(renders[0][0], np.uint8)
    for hit, _ in renders:
        union |= hit.astype(np.uint8)
    size = 2 * (pad + 2) + 1
    grown = cv2.dilate(union, np.ones((size, size), np.uint8)).astype(bool)
    region = shifted(grown, pad, 0, 0)
    return region & ~others if others is not None else region


__all__ = ['AlignedView', 'aligned_view', 'alignment_score', 'best_shift', 'depth_spread_px',
           'measured_heights', 'pixel_votes', 'pooled_votes', 'pose_spread_px', 'render_heights',
           'round_robin', 'shift_of', 'shift_px', 'shifted', 'table_noise_m', 'undominated',
           'view_votes', 'voting_region']
