"""A robot arm hiding part of one camera's view: the synthetic occluder of the two-view tests.

On a flat table, the side camera (70° to the table) sees almost every part: one part rarely
hides another, even in tightly clustered simulated scenes (docs/bench/code-figures.md).
In the cell, what hides a part from one camera is the arm reaching over the table. This module
paints such an arm into one view of a simulated frame after rendering: a straight link of
constant width that enters from the top image border and ends past a chosen part, at a fixed
height above the table. Colour, depth (ray-plane depth of the link), instance image and every
part's visible mask, box and visible fraction are updated, so the view stays self-consistent;
the other view is untouched. Seeded by the caller's generator.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import cv2
import numpy as np

from tlessbot_ros.sim.simulator import SimulatedFrame, SimulatedView


@dataclass(frozen=True)
class ArmOcclusionParams:
    """Arm link settings.

    Attributes:
        height_m: height of the link's underside above the table (its depth in the image).
        margin_px: the link covers the target part's visible box grown by this much.
        grey: mean RGB value of the link (painted aluminium), with a shading ramp across it.
    """

    height_m: float = 0.20
    margin_px: int = 6
    grey: float = 150.0


def arm_mask(shape: tuple[int, int], box: tuple[int, int, int, int], margin_px: int
             ) -> np.ndarray:
    """(H, W) bool: a vertical band from the top border down to the bottom of ``box`` (x, y, w,
    h) grown by ``margin_px``, the image of a link reaching in over the part."""
    height, width = shape
    x, y, w, h = box
    x0, x1 = max(x - margin_px, 0), min(x + w + margin_px, width)
    y1 = min(y + h + margin_px, height)
    mask = np.zeros(shape, bool)
    mask[:y1, x0:x1] = True
    return mask


def _plane_depth_mm(view: SimulatedView, height_m: float) -> np.ndarray:
    """(H, W) float z-depth in mm of the horizontal plane ``z = height_m`` (world frame)."""
    height, width = view.rgb.shape[:2]
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    rays = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(view.intrinsics.K).T
    R, t = view.T_world_camera[:3, :3], view.T_world_camera[:3, 3]
    dz = rays @ R[2]                     # world z change per unit of optical depth
    with np.errstate(divide='ignore', invalid='ignore'):
        depth_m = (height_m - t[2]) / dz
    return np.where(depth_m > 0, depth_m * 1000.0, 0.0)


def occlude_view(view: SimulatedView, target: int, rng: np.random.Generator,
                 params: ArmOcclusionParams = ArmOcclusionParams()) -> SimulatedView:
    """``view`` with an arm link over part ``target`` (index into ``view.gt``)."""
    mask = arm_mask(view.rgb.shape[:2], view.gt[target].bbox_visib, params.margin_px)
    depth_mm = _plane_depth_mm(view, params.height_m)
    # The link must be nearer than what it covers; where the plane is not (grazing rays), the
    # pixel stays as rendered.
    mask &= (depth_mm > 0) & ((view.depth_mm == 0) | (depth_mm < view.depth_mm))
    rgb = view.rgb.copy()
    cols = np.nonzero(mask.any(axis=0))[0]
    if len(cols):
        ramp = np.linspace(-25.0, 25.0, len(cols))   # a cylinder lit from one side
        shade = np.zeros(view.rgb.shape[1])
        shade[cols] = ramp
        value = params.grey + shade[None, :] + rng.normal(0.0, 2.0, mask.shape)
        rgb[mask] = np.clip(value[mask], 0, 255).astype(np.uint8)[:, None]
    new_depth = view.depth_mm.copy()
    new_depth[mask] = np.round(depth_mm[mask]).astype(new_depth.dtype)
    instance = view.instance.copy()
    instance[mask] = -1
    gt = []
    for g in view.gt:
        visible = g.mask_visib & ~mask
        count = int(visible.sum())
        box = tuple(int(v) for v in cv2.boundingRect(visible.astype(np.uint8))) if count else (
            -1, -1, -1, -1)
        gt.append(dataclasses.replace(
            g, mask_visib=visible, px_count_visib=count, bbox_visib=box,
            visib_fract=count / g.px_count_all if g.px_count_all else 0.0))
    clean = view.depth_clean_m.copy()
    clean[mask] = depth_mm[mask] / 1000.0
    return dataclasses.replace(view, rgb=rgb, depth_mm=new_depth, depth_clean_m=clean,
                               instance=instance, gt=gt)


def occlude_frame(frame: SimulatedFrame, view: str, rng: np.random.Generator,
                  params: ArmOcclusionParams = ArmOcclusionParams(), *,
                  min_visib_other: float = 0.5) -> tuple[SimulatedFrame, int | None]:
    """Hide one part of ``frame`` from camera ``view`` under an arm link.

    The part is drawn among those at least ``min_visib_other`` visible in every other view (so
    that the fusion can find it there). Returns the new frame and the part's index, or the
    frame unchanged and None when no part qualifies.
    """
    others = [name for name in frame.views if name != view]
    candidates = [k for k, g in enumerate(frame.views[view].gt)
                  if g.px_count_visib > 0 and all(
                      frame.views[o].gt[k].visib_fract >= min_visib_other for o in others)]
    if not candidates:
        return frame, None
    target = int(rng.choice(candidates))
    views = dict(frame.views)
    views[view] = occlude_view(frame.views[view], target, rng, params)
    return dataclasses.replace(frame, views=views), target
