"""A part's given 2D box in box mode (ground-truth or detector boxes, the paper's "GT box"
setting) as evidence for its pose: the share of the box that a pose's projected model covers.

A box is its part's visible extent, so the right pose's projected model covers all of it (and
reaches beyond it where the part is hidden). In a pile the box also holds its neighbours, and
the pose that explains most of the box's depth can be a neighbour's, lying inside the box:
that pose covers only part of it. The table path (:mod:`.estimator`) weighs every hypothesis,
start and finalist by this cover, so in box mode the fit looks for the pose that explains the
box's depth *and* spans the box.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from tlessbot_ros.core.common import project_points
from tlessbot_ros.core.pose.database import ObjectTemplates


@dataclass(frozen=True)
class ImageBox:
    """A part's box in the image its ROI cloud was read from.

    Attributes:
        box: (x, y, w, h) pixels, the first pixel's column and row and the box's size (w, h
            >= 1), as :func:`~tlessbot_ros.core.common.mask_box` gives them.
        K: (3, 3) that camera's matrix (pixels), the ROI cloud's optical frame.
    """

    box: tuple[int, int, int, int]
    K: np.ndarray

    def __post_init__(self) -> None:
        if len(self.box) != 4 or self.box[2] < 1 or self.box[3] < 1:
            raise ValueError(f'box must be (x, y, w, h) with w, h >= 1, got {self.box}')
        K = np.asarray(self.K, np.float64)
        if K.shape != (3, 3):
            raise ValueError(f'K must be 3x3, got shape {K.shape}')
        object.__setattr__(self, 'K', K)


def extreme_points(obj: ObjectTemplates) -> np.ndarray:
    """(V, 3) float64 the vertices of the convex hull of ``obj``'s surface samples (object
    frame, m): a projected convex set is the hull of the projected vertices, so their image
    extent is the samples' (all of them when the hull cannot be built)."""
    def build() -> np.ndarray:
        points = np.asarray(obj.model_points, np.float64)
        try:
            return cast(np.ndarray, points[ConvexHull(points).vertices])
        except (QhullError, ValueError):
            return points
    return cast(np.ndarray, obj.derived('hull_vertices', build))


def box_cover(T_camera_object: np.ndarray, obj: ObjectTemplates, image_box: ImageBox
              ) -> np.ndarray:
    """(K,) the share (0..1) of ``image_box``'s area inside the image extent (the bounding
    rectangle) of ``obj``'s model at each of K poses.

    Args:
        T_camera_object: (K, 4, 4) or (4, 4) poses in the box's camera frame (m).
        obj: the part's templates (its surface samples).
        image_box: the box and its camera.

    A pose with a model point at or behind the camera plane covers nothing (0).
    """
    T = np.asarray(T_camera_object, np.float64).reshape(-1, 4, 4)
    points = np.einsum('kij,vj->kvi', T[:, :3, :3], extreme_points(obj)) + T[:, None, :3, 3]
    in_front = (points[..., 2] > 1e-6).all(axis=1)
    uv = project_points(points.reshape(-1, 3), image_box.K).reshape(*points.shape[:2], 2)
    uv = np.where(in_front[:, None, None], uv, 0.0)   # behind the camera: covers nothing
    u, v = uv[..., 0], uv[..., 1]
    x, y, w, h = image_box.box
    # Pixel k spans k - 0.5 .. k + 0.5 (centres at integers, as the projection's), and a box
    # holds the pixels whose centre a part covers: it reaches up to half a pixel beyond the
    # part's extent on each side, so the extent is widened by that half pixel.
    across = np.minimum(u.max(axis=1) + 0.5, x + w - 0.5) - \
        np.maximum(u.min(axis=1) - 0.5, x - 0.5)
    down = np.minimum(v.max(axis=1) + 0.5, y + h - 0.5) - np.maximum(v.min(axis=1) - 0.5, y - 0.5)
    cover = np.clip(across, 0.0, None) * np.clip(down, 0.0, None) / float(w * h)
    return np.where(in_front, np.minimum(cover, 1.0), 0.0)


def centred_on_box(T_world_object: np.ndarray, obj: ObjectTemplates, image_box: ImageBox,
                   T_world_camera: np.ndarray) -> np.ndarray:
    """(H, 4, 4) the poses ``T_world_object`` (H, 4, 4; table at world z = 0) shifted along
    the table so that the centre of ``obj``'s extent lies on the ray through the centre of
    ``image_box``: the table path's hypotheses placed by the box rather than by the ROI's
    centroid (which a box's neighbours pull away from its part)."""
    T = np.array(T_world_object, np.float64).reshape(-1, 4, 4)
    points = extreme_points(obj)
    centre_o = 0.5 * (points.min(axis=0) + points.max(axis=0))
    centre_w = np.einsum('hij,j->hi', T[:, :3, :3], centre_o) + T[:, :3, 3]
    x, y, w, h = image_box.box
    ray_c = np.linalg.solve(image_box.K, [x + 0.5 * (w - 1), y + 0.5 * (h - 1), 1.0])
    ray_w, origin_w = T_world_camera[:3, :3] @ ray_c, T_world_camera[:3, 3]
    if abs(ray_w[2]) < 1e-9:   # a ray along the table: no shift
        return T
    along = (centre_w[:, 2] - origin_w[2]) / ray_w[2]
    T[:, :2, 3] += origin_w[:2] + along[:, None] * ray_w[:2] - centre_w[:, :2]
    return T
