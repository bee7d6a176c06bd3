"""The debug overlay of the pose stage drawn on arrays (no ROS): one view's depth in false
colour, the outlines of its instance labels, and each posed part's model points and name."""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from tlessbot_ros.core.common.geometry import project_points, transform_points

OUTLINE_RGB = (255, 255, 0)
MODEL_RGB = (0, 255, 0)
TEXT_RGB = (255, 60, 60)


@dataclass(frozen=True)
class OverlayPart:
    """One posed part to draw.

    Attributes:
        label: text written above its box, e.g. 'obj_05'.
        box: (x, y, w, h) of its region in the view, pixels.
        T_camera_object: (4, 4) its pose in the view's optical frame.
        model_points: (N, 3) model surface points, metres, object frame.
    """

    label: str
    box: tuple[int, int, int, int]
    T_camera_object: np.ndarray
    model_points: np.ndarray


def depth_overlay(depth_m: np.ndarray, labels: np.ndarray, K: np.ndarray,
                  parts: Sequence[OverlayPart], *, point_step: int = 5) -> np.ndarray:
    """(H, W, 3) uint8 RGB: the depth (2nd-98th percentile, near = red) in false colour, 0 where
    invalid, the outlines of the labelled regions, and every part's model points (every
    ``point_step``-th) projected with ``K`` and its label.

    Args:
        depth_m: (H, W) depth in metres, NaN or 0 = invalid.
        labels: (H, W) instance labels of the same view (0 = background).
        K: (3, 3) intrinsics of the view.
    """
    depth = np.nan_to_num(depth_m, nan=0.0)
    valid = depth > 0
    span = np.percentile(depth[valid], [2, 98]) if valid.any() else np.array([0.0, 1.0])
    scaled = np.clip((depth - span[0]) / max(span[1] - span[0], 1e-6), 0, 1)
    canvas = cv2.applyColorMap((255 * (1 - scaled)).astype(np.uint8), cv2.COLORMAP_JET)
    canvas = np.ascontiguousarray(canvas[:, :, ::-1])
    canvas[~valid] = 0
    regions: np.ndarray = labels.astype(np.uint8 if labels.max() < 256 else np.uint16)
    edges = cv2.morphologyEx((regions > 0).astype(np.uint8), cv2.MORPH_GRADIENT,
                             np.ones((3, 3), np.uint8)) > 0
    canvas[edges] = OUTLINE_RGB
    for part in parts:
        model = part.model_points[::point_step]
        uv = project_points(transform_points(part.T_camera_object, model), K)
        uv = np.round(uv[np.isfinite(uv).all(axis=1)]).astype(int)
        inside = (uv[:, 0] >= 0) & (uv[:, 0] < canvas.shape[1]) & (uv[:, 1] >= 0) & \
            (uv[:, 1] < canvas.shape[0])
        canvas[uv[inside, 1], uv[inside, 0]] = MODEL_RGB
        x, y, _, _ = part.box
        cv2.putText(canvas, part.label, (x, max(12, y - 4)), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                    TEXT_RGB, 1, cv2.LINE_AA)
    return canvas
