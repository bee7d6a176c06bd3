"""Fusion of the top and side segmentations into instances with one id in both views.

Three methods, selected by :attr:`FusionParams.method`:

* ``'side_only'``: the side segmentation alone (the baseline); the top image gets no labels.
* ``'algorithm1'``: the paper's Algorithm 1 as written (Sensors 2020, §3.1): if the top and
  side box counts agree, the side view is used as it is; otherwise each top box's corners are
  carried into the side view and the side box that receives several top boxes is divided; a
  top box that matches no side box is an object fully occluded in the side view. The paper does
  not say how corners correspond between the views; we carry them with the table-plane
  homography of the calibrated rig (the least calibration the step can work with) and divide a
  side box by vertical cuts half-way between the carried boxes, which is all a box-level
  method can do.
* ``'calibrated'`` (ours): each top blob is lifted into the world (from the top depth image when
  given, else onto the table plane z = 0 and a prism of ``prism_height_m``), extruded down to
  the table, projected into the side camera and painted far-to-near, which predicts where each
  object is visible in the side view and which parts hide others. A side blob that holds
  several predictions is divided by a watershed seeded with them (so the cut follows the
  image's edges); side blobs that carry the same prediction share its id; objects with no
  visible side pixels are reported as seen from the top only.

The hand-off contract: ``FusionResult.labels['top']`` and ``['side']`` are (H, W) uint16 label
images, 0 = background, with the **same id for the same object in both views**; the pose
estimator uses the side view when an instance has side pixels, else the top view.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.optimize import linear_sum_assignment

from tlessbot_ros.core.common import Rig, pixel_counts, transform_points
from tlessbot_ros.core.localise.instances import _fill_from_nearest, boxes_from_labels
from tlessbot_ros.core.localise.segmentation import Segmentation

FUSION_METHODS = ('side_only', 'algorithm1', 'calibrated')


@dataclass(frozen=True)
class FusionParams:
    """Tuning of :func:`fuse_views`.

    Attributes:
        method: one of ``FUSION_METHODS``.
        prism_height_m: height of the prism a top blob is lifted to when there is no top depth.
        min_height_m: lifted points lower than this above the table are table (ignored).
        max_height_m: lifted points higher than this are noise (ignored).
        pixel_step: use every n-th pixel of a top blob when lifting it (speed).
        min_overlap_px: smallest overlap (pixels) of a predicted region with a side blob for a
            match.
        min_overlap_fraction: ... and as a fraction of the predicted visible region.
        min_visible_px: a prediction with fewer visible side pixels than this is treated as
            occluded in the side view.
        seed_erode_px: predicted regions are eroded by this radius before seeding the split.
        fragment_fraction: a side blob matching no prediction by the rules above but lying
            at least this much inside one joins it (fragments of one part share its id).
        drop_unpredicted: drop side blobs that no top blob predicts (fewer false positives
            when the top view sees the whole work area; off by default).
        keep_depth_splits: a side blob that one top blob predicts but whose side
            segmentation divided it by depth (``Segmentation.depth_groups``: two parts whose
            seam the side depth shows, e.g. one in front of the other, that the top view saw
            as one) keeps those pieces apart: the piece the prediction covers most takes the
            top blob's id, the others new ids (seen from the side only).
        box_margin_px: Algorithm 1: tolerance when testing whether a carried foot point lies
            in a side box.
    """

    method: str = 'calibrated'
    prism_height_m: float = 0.03
    min_height_m: float = 0.003
    max_height_m: float = 0.30
    pixel_step: int = 2
    min_overlap_px: int = 40
    min_overlap_fraction: float = 0.15
    min_visible_px: int = 40
    seed_erode_px: int = 2
    box_margin_px: int = 6
    fragment_fraction: float = 0.5
    drop_unpredicted: bool = False
    keep_depth_splits: bool = True

    def __post_init__(self) -> None:
        if self.method not in FUSION_METHODS:
            raise ValueError(f'method must be one of {FUSION_METHODS}, got {self.method!r}')
        if self.pixel_step < 1:
            raise ValueError(f'pixel_step must be >= 1, got {self.pixel_step}')
        if not 0.0 <= self.min_overlap_fraction <= 1.0:
            raise ValueError('min_overlap_fraction must be in [0, 1], got '
                             f'{self.min_overlap_fraction}')


@dataclass
class FusedInstance:
    """One object after fusion.

    Attributes:
        instance_id: its id in both label images (1..65535).
        in_top, in_side: whether it has pixels in that view's label image.
        box_top, box_side: (x, y, w, h) int pixels in that view, or None.
        area_top, area_side: pixel counts.
        split: True if its side pixels were cut out of a blob holding several objects.
    """

    instance_id: int
    in_top: bool
    in_side: bool
    box_top: tuple[int, int, int, int] | None = None
    box_side: tuple[int, int, int, int] | None = None
    area_top: int = 0
    area_side: int = 0
    split: bool = False

    @property
    def views(self) -> tuple[str, ...]:
        return tuple(v for v, on in (('top', self.in_top), ('side', self.in_side)) if on)

    @property
    def preferred_view(self) -> str:
        """The view the pose estimator should use: side when visible there, else top."""
        return 'side' if self.in_side else 'top'


@dataclass
class FusionResult:
    """Output of :func:`fuse_views` for one frame pair.

    Attributes:
        labels: {'top': (H, W) uint16, 'side': (H, W) uint16}, 0 = background, one id per
            object shared by both views.
        instances: the objects, sorted by id.
        method: the method used.
        predicted_side: (H, W) uint16 predicted visible side regions (calibrated method only;
            ids as in ``labels``), for inspection.
        timings_ms: wall time per stage.
    """

    labels: dict[str, np.ndarray]
    instances: list[FusedInstance]
    method: str
    predicted_side: np.ndarray | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)

    def instance(self, instance_id: int) -> FusedInstance:
        for inst in self.instances:
            if inst.instance_id == instance_id:
                return inst
        raise KeyError(f'no instance {instance_id}')


def fuse_views(top: Segmentation, side: Segmentation, *, rig: Rig | None = None,
               depth_top_m: np.ndarray | None = None, side_rgb: np.ndarray | None = None,
               params: FusionParams = FusionParams(), top_name: str = 'top',
               side_name: str = 'side') -> FusionResult:
    """Give each object one id in both views (paper's Algorithm 1 or the calibrated fusion).

    Args:
        top, side: :class:`~tlessbot_ros.core.localise.Segmentation` of each view.
        rig: the calibrated cameras (intrinsics + extrinsics, world z = 0 is the table);
            needed by 'algorithm1' (plane homography) and 'calibrated'.
        depth_top_m: optional (H, W) float32 top depth in metres (0 / NaN invalid), aligned to
            the top colour image; improves the lifting of top blobs.
        side_rgb: optional (H, W, 3) uint8 side image; the split follows its edges.
        params: see :class:`FusionParams`.
        top_name, side_name: camera names in ``rig``.

    Returns:
        :class:`FusionResult`.
    """
    t0 = time.perf_counter()
    if params.method == 'side_only':
        result = _side_only(top, side)
    else:
        if rig is None:
            raise ValueError(f'method {params.method!r} needs the calibrated rig (rig=...)')
        if params.method == 'algorithm1':
            result = _algorithm1(top, side, rig, params, top_name, side_name)
        else:
            result = _calibrated(top, side, rig, depth_top_m, side_rgb, params, top_name,
                                 side_name)
    result.timings_ms['total'] = (time.perf_counter() - t0) * 1e3
    return result


# --------------------------------------------------------------------------- helpers
def _instances_from_labels(top_labels: np.ndarray, side_labels: np.ndarray,
                           split_ids: set[int]) -> list[FusedInstance]:
    n = int(max(top_labels.max(initial=0), side_labels.max(initial=0)))
    if n == 0:
        return []
    tb, ta = boxes_from_labels(top_labels)
    sb, sa = boxes_from_labels(side_labels)
    out = []
    for i in range(1, n + 1):
        at = int(ta[i - 1]) if i <= ta.size else 0
        as_ = int(sa[i - 1]) if i <= sa.size else 0
        if at == 0 and as_ == 0:
            continue
        out.append(FusedInstance(
            instance_id=i, in_top=at > 0, in_side=as_ > 0,
            box_top=tuple(int(v) for v in tb[i - 1]) if at else None,
            box_side=tuple(int(v) for v in sb[i - 1]) if as_ else None,
            area_top=at, area_side=as_, split=i in split_ids))
    return out


def _side_only(top: Segmentation, side: Segmentation) -> FusionResult:
    labels = {'top': np.zeros_like(top.labels), 'side': side.labels.astype(np.uint16)}
    return FusionResult(labels=labels, method='side_only',
                        instances=_instances_from_labels(labels['top'], labels['side'], set()))


def table_homography(rig: Rig, camera: str) -> np.ndarray:
    """(3, 3) homography from table-plane (world x, y at z = 0, metres) to ``camera`` pixels."""
    mount = rig[camera]
    T = mount.T_camera_world
    return mount.intrinsics.K @ np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]])


def _apply_h(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    return p[:, :2] / p[:, 2:3]


# --------------------------------------------------------------------------- Algorithm 1
def _algorithm1(top: Segmentation, side: Segmentation, rig: Rig, params: FusionParams,
                top_name: str, side_name: str) -> FusionResult:
    H_top = table_homography(rig, top_name)
    H_top_to_side = table_homography(rig, side_name) @ np.linalg.inv(H_top)
    n_top, n_side = top.count, side.count
    top_labels = top.labels.astype(np.uint16)
    side_labels = np.zeros_like(side.labels, dtype=np.uint16)
    split_ids: set[int] = set()
    # Carried top boxes: the four corners through the table homography.
    carried = []
    for x, y, w, h in top.boxes:
        corners = np.array([[x, y], [x + w - 1, y], [x, y + h - 1], [x + w - 1, y + h - 1]],
                           float)
        c = _apply_h(H_top_to_side, corners)
        carried.append((c[:, 0].min(), c[:, 1].min(), c[:, 0].max(), c[:, 1].max()))
    next_id = n_top + 1
    if n_top == n_side and n_top > 0:
        # Counts agree: use the side view; pair boxes by carried foot point (bottom centre).
        cost = np.zeros((n_top, n_side))
        for i, (x0, _y0, x1, y1) in enumerate(carried):
            foot = np.array([(x0 + x1) / 2, y1])
            for j, (x, y, w, h) in enumerate(side.boxes):
                cost[i, j] = np.hypot(foot[0] - (x + w / 2), foot[1] - (y + h))
        rows, cols = linear_sum_assignment(cost)
        for i, j in zip(rows, cols):
            side_labels[side.labels == j + 1] = i + 1
    else:
        matches: dict[int, list[int]] = {}
        m = params.box_margin_px
        for i, (x0, y0, x1, y1) in enumerate(carried):
            cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
            for j, (x, y, w, h) in enumerate(side.boxes):
                if x - m <= cx <= x + w - 1 + m and y - m <= cy <= y + h - 1 + m:
                    matches.setdefault(j, []).append(i)
                    break  # first containing box, as the corner test would give
        for j in range(n_side):
            blob = side.labels == j + 1
            owners = matches.get(j, [])
            if not owners:
                side_labels[blob] = next_id  # seen only from the side
                next_id += 1
            elif len(owners) == 1:
                side_labels[blob] = owners[0] + 1
            else:
                # Divide the box: vertical cuts half-way between the carried box centres.
                centres = sorted(((carried[i][0] + carried[i][2]) / 2, i) for i in owners)
                cuts = [(a[0] + b[0]) / 2 for a, b in zip(centres, centres[1:])]
                ys, xs = np.nonzero(blob)
                which = np.searchsorted(np.array(cuts), xs)
                ids = np.array([i + 1 for _, i in centres], np.uint16)
                side_labels[ys, xs] = ids[which]
                split_ids.update(int(i) for i in ids)
    labels = {'top': top_labels, 'side': side_labels}
    return FusionResult(labels=labels, method='algorithm1',
                        instances=_instances_from_labels(top_labels, side_labels, split_ids))


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


def _calibrated(top: Segmentation, side: Segmentation, rig: Rig,
                depth_top_m: np.ndarray | None, side_rgb: np.ndarray | None,
                params: FusionParams, top_name: str, side_name: str) -> FusionResult:
    timings: dict[str, float] = {}
    t0 = time.perf_counter()
    top_labels = top.labels.astype(np.uint16)
    if depth_top_m is not None and depth_top_m.shape != top_labels.shape:
        raise ValueError(f'depth_top_m shape {depth_top_m.shape} differs from the top labels '
                         f'{top_labels.shape}; align depth to colour first')
    points = lift_top_blobs(top_labels, rig, depth_top_m=depth_top_m, params=params,
                            top_name=top_name)
    pred = predict_side_regions(points, rig, side_name=side_name)
    if pred.shape != side.labels.shape:
        raise ValueError(f'side image {side.labels.shape} differs from the rig side camera '
                         f'{pred.shape}')
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
    kernel = cv2.getStructuringElement(
        cv2.MORPH_ELLIPSE, (2 * params.seed_erode_px + 1, 2 * params.seed_erode_px + 1))
    for b in range(1, n_blobs):
        owners = [k for k in range(1, n_top + 1)
                  if overlap[b, k] >= params.min_overlap_px
                  and pred_area[k] >= params.min_visible_px
                  and overlap[b, k] >= params.min_overlap_fraction * pred_area[k]]
        # Work in the blob's box plus a 1-pixel margin instead of the whole image: a few small
        # parts cover a few % of it.
        x, y, w, h = (int(v) for v in stats[b, :4])
        window = (slice(max(y - 1, 0), y + h + 1), slice(max(x - 1, 0), x + w + 1))
        blob = blobs[window] == b
        out = side_labels[window]
        if not owners and n_top > 0:
            # A fragment (e.g. of a dark part on a dark square) lying inside one prediction.
            best = int(np.argmax(overlap[b, 1:])) + 1
            if overlap[b, best] >= params.fragment_fraction * stats[b, cv2.CC_STAT_AREA]:
                owners = [best]
        if not owners and params.drop_unpredicted:
            continue
        if not owners:
            # Not predicted from the top: keep the side segmentation's own instances.
            own = side.labels[window]
            for j in np.unique(own[blob]):
                if j:
                    out[blob & (own == j)] = next_id
                    next_id += 1
        elif len(owners) == 1:
            pieces = _depth_pieces_of_blob(blob, side.labels[window], side.depth_groups,
                                           params) if params.keep_depth_splits else []
            if len(pieces) < 2:
                out[blob] = owners[0]
            else:
                mine = pred[window] == owners[0]
                first = int(np.argmax([np.count_nonzero(p & mine) for p in pieces]))
                for j, piece in enumerate(pieces):
                    if j == first:
                        out[piece] = owners[0]
                    else:
                        out[piece] = next_id
                        next_id += 1
                split_ids.add(owners[0])
        else:
            out[blob] = _divide_among_owners(blob, pred[window], owners,
                                             None if side_rgb is None else side_rgb[window],
                                             kernel)
            split_ids.update(owners)
    timings['split'] = (time.perf_counter() - t1) * 1e3
    labels = {'top': top_labels, 'side': side_labels}
    return FusionResult(labels=labels, method='calibrated', predicted_side=pred,
                        instances=_instances_from_labels(top_labels, side_labels, split_ids),
                        timings_ms=timings)


def _depth_pieces_of_blob(blob: np.ndarray, own: np.ndarray, depth_groups: np.ndarray,
                          params: FusionParams) -> list[np.ndarray]:
    """The pieces of one side blob that its segmentation's depth split made: one bool mask
    per depth group (the blob's pixels of other labels join the nearest piece); none unless
    there are two or more, each with ``min_visible_px`` pixels.

    ``blob`` and ``own`` (the side segmentation's labels) are cut to the blob's window."""
    ids = np.unique(own[blob])
    ids = ids[(ids > 0) & (ids <= len(depth_groups))]
    groups = depth_groups[ids - 1] if ids.size else ids
    if np.count_nonzero(np.unique(groups)) < 2:
        return []
    group_of = np.zeros(int(own.max()) + 1, np.int32)
    group_of[ids] = groups
    grouped = np.where(blob, group_of[own], 0)
    holes = blob & (grouped == 0)
    if holes.any():
        _fill_from_nearest(grouped, holes)
    pieces = [grouped == g for g in np.unique(groups) if g]
    if any(np.count_nonzero(p) < params.min_visible_px for p in pieces):
        return []
    return pieces


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
        _fill_from_nearest(ids, holes)
    return ids[blob].astype(np.uint16)


__all__ = ['FUSION_METHODS', 'FusedInstance', 'FusionParams', 'FusionResult', 'fuse_views',
           'lift_top_blobs', 'predict_side_regions', 'table_homography']
