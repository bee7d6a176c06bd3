"""A region's rim of blended colour peeled off (issue 41).

A camera's optics blend a part's colour with the colour beside it over a pixel or two along
the part's outline. The localiser's region takes that ring in (its cues are read at half
resolution; a small part's region is grown by the depth to the part's rim), and the ring
widens the region's box by a pixel a side: for a part n pixels across the box's IoU with the
part's own is (n / (n + 2))^2, under 0.7 up to n = 10.

A pixel of the ring is a blend ``c = a p + (1 - a) t`` of the part's colour ``p`` and the
colour beside it ``t``; ``a`` is about the share of the pixel the part covers, and a pixel
belongs to the part's mask where its centre lies on the part, ``a`` above one half. So, once
a frame's parts are fitted, each region's outer pixels (one of their 8 neighbours outside
it) are read once in CIE-LAB: ``p`` is the mean colour of the region's pixels at least
:data:`INNER_PX` inside it within :data:`LOCAL_PX` of the pixel (a part's faces are shaded
apart), ``t`` the colour of the pixel outside the region by at least one pixel, within
:data:`BESIDE_PX`, that explains the pixel best as a blend with ``p`` (a patterned table
changes colour a few pixels on), and ``a`` the pixel's colour projected on the segment from
``t`` to ``p``. A pixel whose ``a`` lies below ``FitParams.rim_colour_below`` (0.5 where
used: the mask's own rule; off by default) is dropped from its region, where ``p`` and ``t``
differ by :data:`MIN_CONTRAST` at least (else ``a`` is noise). One ring only: the next one in
is the part's own. Every region of every view is read, named or not; a fitted part's box
follows its region; poses are not changed.

The rule reads colour alone: where the image draws a part's outline sharp and its rim lit
or shaded unlike its middle (a renderer without blur), or where the region holds no ring (a
tight region from per-pixel depth), it drops the part's own rim (docs/bench/colour-rims.md).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import cv2
import numpy as np

from tlessbot_ros.core.common import mask_box
from tlessbot_ros.core.frame import Detection, ViewInput
from tlessbot_ros.core.localise.colour import rgb_to_lab
from tlessbot_ros.core.region_trim import trim_to_fits

if TYPE_CHECKING:
    from tlessbot_ros.core.pipeline import PerceptionPipeline

# The region's own colour is read within this many pixels of the rim pixel (a square
# window), the colour beside it among the outside pixels within BESIDE_PX (the nearest ones).
LOCAL_PX = 4
BESIDE_PX = 2
# A region's own colour is read this many pixels inside its outline: past the blended ring.
INNER_PX = 2
# Below this CIE-LAB distance (Delta E 1976) between the inside and outside colours the
# projection is mostly noise (a just noticeable difference is about 2.3).
MIN_CONTRAST = 10.0

_SQUARE = np.ones((3, 3), np.uint8)


def rim_pixels_to_drop(lab: np.ndarray, region: np.ndarray, below: float) -> np.ndarray:
    """(H, W) bool: the outer pixels of ``region`` ((H, W) bool) whose blend share ``a`` of
    the region's local colour lies below ``below`` (see the module), in ``lab`` ((H, W, 3)
    float32 CIE-LAB); ``region`` should lie :data:`LOCAL_PX` + 1 pixels inside the image
    given, or the window's edge cuts its reading."""
    inside = region.astype(np.uint8)
    core = cv2.erode(inside, _SQUARE, iterations=INNER_PX).astype(bool)
    part, n_part = _local_mean(lab, core, LOCAL_PX)
    ys, xs = np.nonzero(region & ~cv2.erode(inside, _SQUARE).astype(bool) & (n_part > 0))
    drop = np.zeros(region.shape, bool)
    if ys.size == 0:
        return drop
    beside = ~cv2.dilate(inside, _SQUARE).astype(bool)
    dy, dx = np.mgrid[-BESIDE_PX:BESIDE_PX + 1, -BESIDE_PX:BESIDE_PX + 1].reshape(2, 1, -1)
    near_y, near_x = ys[:, None] + dy[0], xs[:, None] + dx[0]   # (N, K) the window's pixels
    height, width = region.shape
    in_image = (near_y >= 0) & (near_y < height) & (near_x >= 0) & (near_x < width)
    near_y, near_x = np.clip(near_y, 0, height - 1), np.clip(near_x, 0, width - 1)
    table = lab[near_y, near_x]   # (N, K, 3)
    step = part[ys, xs][:, None, :] - table
    contrast2 = np.einsum('nkc,nkc->nk', step, step)
    colour = lab[ys, xs][:, None, :]
    share = np.einsum('nkc,nkc->nk', colour - table, step) / np.maximum(contrast2, 1e-6)
    misfit = colour - table - np.clip(share, 0.0, 1.0)[..., None] * step
    misfit2 = np.where(in_image & beside[near_y, near_x] & (contrast2 >= MIN_CONTRAST ** 2),
                       np.einsum('nkc,nkc->nk', misfit, misfit), np.inf)
    best = np.argmin(misfit2, axis=1)
    rows = np.arange(ys.size)
    read = np.isfinite(misfit2[rows, best])
    drop[ys[read], xs[read]] = share[rows, best][read] < below
    return drop


def _local_mean(lab: np.ndarray, mask: np.ndarray, reach_px: int
                ) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) mean of ``lab`` over ``mask``'s pixels within ``reach_px`` of each pixel
    (a square window), and (H, W) their count."""
    size = (2 * reach_px + 1,) * 2
    weight = mask.astype(np.float32)
    count = cv2.boxFilter(weight, -1, size, normalize=False, borderType=cv2.BORDER_CONSTANT)
    total = cv2.boxFilter(lab * weight[..., None], -1, size, normalize=False,
                          borderType=cv2.BORDER_CONSTANT)
    return total / np.maximum(count, 1.0)[..., None], count


def peel_colour_rims(views: dict[str, ViewInput], labels: dict[str, np.ndarray],
                     detections: list[Detection], below: float, *,
                     box_mode: bool = False) -> list[Detection]:
    """``detections``, every region of every view of ``labels`` with its outer pixels of
    blended colour dropped (:func:`rim_pixels_to_drop`, ``below``: 0 turns it off); nothing
    in ``box_mode`` (a region is the part's given box). ``labels``' arrays are replaced,
    not written into; each detection's ``box`` follows its region in its view."""
    if below <= 0 or box_mode:
        return detections
    reach = LOCAL_PX + INNER_PX + 1
    for name, image in labels.items():
        view = views.get(name)
        if view is None or view.rgb is None or view.rgb.shape[:2] != image.shape:
            continue
        peeled = image.copy()
        for instance in (int(i) for i in np.unique(image) if i):
            x, y, w, h = mask_box(image == instance)
            y0, x0 = max(0, y - reach), max(0, x - reach)
            window = (slice(y0, y + h + reach), slice(x0, x + w + reach))
            drop = rim_pixels_to_drop(rgb_to_lab(np.ascontiguousarray(view.rgb[window])),
                                      image[window] == instance, below)
            peeled[window][drop] = 0
        labels[name] = peeled
    for detection in detections:
        if detection.view in labels:
            detection.box = mask_box(labels[detection.view] == detection.instance_id)
    return detections


def trim_after_fits(pipeline: PerceptionPipeline, views: dict[str, ViewInput],
                    labels: dict[str, np.ndarray], detections: list[Detection], *,
                    box_mode: bool = False) -> list[Detection]:
    """``detections`` with their regions trimmed once the frame's parts are fitted: to the
    fitted outlines (:func:`~tlessbot_ros.core.region_trim.trim_to_fits`), then every
    region's ring of blended colour peeled (:func:`peel_colour_rims`,
    ``FitParams.rim_colour_below``)."""
    trim_to_fits(pipeline, views, labels, detections, box_mode=box_mode)
    return peel_colour_rims(views, labels, detections, pipeline.fit_params.rim_colour_below,
                            box_mode=box_mode)


__all__ = ['BESIDE_PX', 'INNER_PX', 'LOCAL_PX', 'MIN_CONTRAST', 'peel_colour_rims',
           'rim_pixels_to_drop', 'trim_after_fits']
