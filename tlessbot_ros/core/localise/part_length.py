"""How long a region of one view is on the table, in metres, from that view's depth: a region
longer than the longest part of the set holds several parts; and whether a thin region's
outline on the table fits some part's (:func:`fits_a_part`).

The parts' largest extents are known (``SegmentationParams.whole_parts``); the image length of
a region is not enough to compare with them, since a part's image length depends on where it
lies and how it is turned. Its depth, lifted into the table frame, gives the region's points;
their spread along their main direction on the table (between the ``_TAIL`` and the
``1 - _TAIL`` quantiles, so the few mixed pixels a stereo-like depth puts beyond a part's
outline do not count) is a length that a whole part cannot exceed by more than that noise.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from tlessbot_ros.core.common import Rig, depth_to_points, transform_points

# The share of a region's points left out at each end of its length.
_TAIL = 0.01
# The fewest points a length is read from.
_MIN_POINTS = 30


@dataclass(frozen=True)
class ViewDepth:
    """One view's depth and camera, to lift the pixels of a region into the table frame.

    Attributes:
        depth_m: (H, W) float depth in metres (0 / NaN invalid), aligned to the labels.
        K: (3, 3) the camera's intrinsics.
        T_world_camera: (4, 4) the camera's pose in the table frame (z up, table at z = 0).
        min_height_m: points lower than this above the table are table, not part.
    """

    depth_m: np.ndarray
    K: np.ndarray
    T_world_camera: np.ndarray
    min_height_m: float = 0.004

    def table_xy(self, mask: np.ndarray, origin: tuple[int, int] = (0, 0)) -> np.ndarray:
        """(N, 2) float64 table-frame x, y (m) of the valid pixels of ``mask`` (a bool crop
        whose first pixel is ``origin`` = (row, column) of the image) higher than
        ``min_height_m`` above the table."""
        row0, col0 = origin
        rows, cols = mask.shape
        K = np.array(self.K, np.float64)   # the crop's camera: the principal point moves
        K[0, 2] -= col0
        K[1, 2] -= row0
        cam, _ = depth_to_points(self.depth_m[row0:row0 + rows, col0:col0 + cols], K,
                                 mask=mask)
        world = transform_points(self.T_world_camera, cam.astype(np.float64))
        raised: np.ndarray = world[world[:, 2] > self.min_height_m, :2]
        return raised


def table_length_m(xy: np.ndarray) -> float:
    """The length (m) of (N, 2) table points along their main direction, between the
    ``_TAIL`` and ``1 - _TAIL`` quantiles; 0 with fewer than ``_MIN_POINTS`` points."""
    return table_extents_m(xy)[0]


def table_extents_m(xy: np.ndarray) -> tuple[float, float]:
    """(length, width) in m of (N, 2) table points along their main direction and across it,
    each between the ``_TAIL`` and ``1 - _TAIL`` quantiles; 0, 0 with fewer than
    ``_MIN_POINTS`` points."""
    if len(xy) < _MIN_POINTS:
        return 0.0, 0.0
    centred = xy - xy.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    extents = [np.quantile(centred @ axis, [_TAIL, 1.0 - _TAIL]) for axis in axes[:2]]
    return float(extents[0][1] - extents[0][0]), float(extents[1][1] - extents[1][0])


def table_homography(rig: Rig, camera: str) -> np.ndarray:
    """(3, 3) homography from table-plane (world x, y at z = 0, metres) to ``camera`` pixels."""
    mount = rig[camera]
    T = mount.T_camera_world
    return cast(np.ndarray, mount.intrinsics.K @ np.column_stack([T[:3, 0], T[:3, 1], T[:3, 3]]))


def fits_a_part(mask: np.ndarray, origin: tuple[int, int], H_table_to_image: np.ndarray,
                footprints_m: tuple[tuple[float, float], ...], ratio: float) -> bool:
    """Whether a thin region ``mask`` (a bool crop at ``origin`` = (row, column)) lies on the
    table within ``ratio`` times some part's two largest extents (``footprints_m``, m): its
    pixels carried onto the table plane (``H_table_to_image``, :func:`table_homography`; a
    thin part lies within its thickness of that plane), measured by :func:`table_extents_m`.
    Two thin parts touching make a region longer or wider than any part. True with fewer
    than ``_MIN_POINTS`` pixels."""
    rows, cols = np.nonzero(mask)
    if len(rows) < _MIN_POINTS:
        return True
    pixels = np.column_stack([cols + origin[1], rows + origin[0], np.ones(len(rows))])
    carried = pixels @ np.linalg.inv(H_table_to_image).T
    length, width = table_extents_m(carried[:, :2] / carried[:, 2:3])
    return any(length <= ratio * max(a, b) and width <= ratio * min(a, b)
               for a, b in footprints_m)


def longer_than_parts(depth: ViewDepth | None, whole_parts: np.ndarray, ratio: float,
                      mask: np.ndarray, origin: tuple[int, int] = (0, 0)) -> bool:
    """Whether the region ``mask`` (a bool crop at ``origin``) is longer on the table than
    ``ratio`` times the longest part (``whole_parts[:, 0]``, m): several parts. False without
    the view's depth, the parts or a ratio (0: off)."""
    if depth is None or ratio <= 0 or not len(whole_parts):
        return False
    longest = float(np.max(whole_parts[:, 0]))
    return table_length_m(depth.table_xy(mask, origin)) > ratio * longest


__all__ = ['ViewDepth', 'fits_a_part', 'longer_than_parts', 'table_extents_m', 'table_homography',
           'table_length_m']
