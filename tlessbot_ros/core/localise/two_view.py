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
from typing import cast

import numpy as np
from scipy.optimize import linear_sum_assignment

from tlessbot_ros.core.common import Rig
from tlessbot_ros.core.localise.calibrated_fusion import (
    calibrated_fusion,
    lift_top_blobs,
    predict_side_regions,
)
from tlessbot_ros.core.localise.fusion_result import (
    FUSION_METHODS,
    FusedInstance,
    FusionParams,
    FusionResult,
    instances_from_labels,
)
from tlessbot_ros.core.localise.part_length import table_homography
from tlessbot_ros.core.localise.segmentation import Segmentation


def fuse_views(top: Segmentation, side: Segmentation, *, rig: Rig | None = None,
               depth_top_m: np.ndarray | None = None, side_rgb: np.ndarray | None = None,
               params: FusionParams = FusionParams(), top_name: str = 'top',
               side_name: str = 'side', top_rgb: np.ndarray | None = None) -> FusionResult:
    """Give each object one id in both views (paper's Algorithm 1 or the calibrated fusion).

    Args:
        top, side: :class:`~tlessbot_ros.core.localise.Segmentation` of each view.
        rig: the calibrated cameras (intrinsics + extrinsics, world z = 0 is the table);
            needed by 'algorithm1' (plane homography) and 'calibrated'.
        depth_top_m: optional (H, W) float32 top depth in metres (0 / NaN invalid), aligned to
            the top colour image; improves the lifting of top blobs.
        side_rgb: optional (H, W, 3) uint8 side image; the split follows its edges.
        top_rgb: optional (H, W, 3) uint8 top image (``lightness_top_ratio``).
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
            result = calibrated_fusion(top, side, rig, depth_top_m, side_rgb, params, top_name,
                                       side_name, top_rgb=top_rgb)
    result.timings_ms['total'] = (time.perf_counter() - t0) * 1e3
    return result




def single_view(segmentation: Segmentation, name: str) -> FusionResult:
    """The instances of a rig of one camera: its segmentation's labels as they are, under the
    camera's ``name`` (:attr:`FusionResult.labels` has that one view; the instances count as
    seen from the top for a camera named ``top``, else from the side)."""
    t0 = time.perf_counter()
    labels = segmentation.labels.astype(np.uint16)
    empty = np.zeros_like(labels)
    instances = instances_from_labels(*((labels, empty) if name == 'top' else (empty, labels)),
                                      set())
    result = FusionResult(labels={name: labels}, instances=instances, method='single_view')
    result.timings_ms['total'] = (time.perf_counter() - t0) * 1e3
    return result


def _side_only(top: Segmentation, side: Segmentation) -> FusionResult:
    labels = {'top': np.zeros_like(top.labels), 'side': side.labels.astype(np.uint16)}
    return FusionResult(labels=labels, method='side_only',
                        instances=instances_from_labels(labels['top'], labels['side'], set()))


def _apply_h(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    p = np.column_stack([xy, np.ones(len(xy))]) @ H.T
    return cast(np.ndarray, p[:, :2] / p[:, 2:3])


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
                        instances=instances_from_labels(top_labels, side_labels, split_ids))


__all__ = ['FUSION_METHODS', 'FusedInstance', 'FusionParams', 'FusionResult', 'fuse_views',
           'lift_top_blobs', 'predict_side_regions', 'single_view', 'table_homography']
