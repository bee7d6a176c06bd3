"""A flat part seen along its thin axis: the image of its outline, holes included, and whether a
rigid transform keeps it (:func:`~tlessbot_ros.core.common.symmetry_detect.detect_symmetries`
asks it of a flat part's candidate symmetries)."""
from __future__ import annotations

import cv2
import numpy as np

from tlessbot_ros.core.common.sampling import sample_surface


class OutlineTest:
    """A flat part seen along its thin axis: the image of its outline, holes included.

    The surface test weighs the surface by area, and a plate's two large faces outvote its
    holes, notches and cut corners (a hole 6 mm wide in a plate 60 x 40 mm is 1 % of its
    surface): a half turn that moves one hole passes it. Seen from above, where the camera
    sees a flat part, such a feature is as large as it is. The surface samples are projected
    along the thin axis into an image of ``pixel_m`` pixels; a transform moves the outline when
    the pixels where the two images differ, opened by one pixel (edges that differ by less
    than the tolerance, the samples' speckle), exceed ``share`` of the outline's area.
    """

    def __init__(self, points: np.ndarray, axes: np.ndarray, pixel_m: float,
                 share: float) -> None:
        self.points = points
        self.centre = points.mean(axis=0)
        self.basis = axes[:2]   # the two long principal axes (rows)
        self.pixel_m, self.share = pixel_m, share
        uv = (points - self.centre) @ self.basis.T
        reach = float(np.abs(uv).max()) + 3 * pixel_m
        self.size = int(np.ceil(2 * reach / pixel_m)) + 1
        self.origin = -reach
        self.image = self._image(uv)

    def _image(self, uv: np.ndarray) -> np.ndarray:
        ij = np.floor((uv - self.origin) / self.pixel_m).astype(int)
        inside = ((ij >= 0) & (ij < self.size)).all(axis=1)
        image = np.zeros((self.size, self.size), np.uint8)
        image[ij[inside, 0], ij[inside, 1]] = 1
        return cv2.morphologyEx(image, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))

    def disputed(self, T: np.ndarray) -> float:
        """Share of the outline's area the outline moved by ``T`` (4, 4) disputes."""
        moved = self.points @ T[:3, :3].T + T[:3, 3]
        other = self._image((moved - self.centre) @ self.basis.T)
        differ = cv2.morphologyEx(self.image ^ other, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        return float(np.count_nonzero(differ)) / max(1, int(np.count_nonzero(self.image)))

    def moves(self, T: np.ndarray) -> bool:
        return self.disputed(T) > self.share


def outline_test(vertices: np.ndarray, faces: np.ndarray, reference: np.ndarray, *,
                 flat_ratio: float, pixel_m: float, samples: int,
                 share: float, seed: int, scheme: str) -> OutlineTest | None:
    """The :class:`OutlineTest` of a part (None: the part is not flat: its thinnest principal
    extent, ``reference`` (N, 3) surface samples, above ``flat_ratio`` of its middle one);
    ``samples`` surface points (``seed``, ``scheme``: :func:`~.sampling.sample_surface`)
    projected into pixels of ``pixel_m``; a transform moves the outline when the disputed
    pixels, after an opening of one pixel (features narrower than three pixels are ignored),
    exceed ``share`` of the outline's area."""
    centred = reference - reference.mean(axis=0)
    axes = np.linalg.svd(centred, full_matrices=False)[2]   # rows, longest extent first
    extent = np.ptp(centred @ axes.T, axis=0)
    if extent[2] > flat_ratio * extent[1]:
        return None
    points, _ = sample_surface(vertices, faces, samples, seed=seed, scheme=scheme)
    return OutlineTest(points, axes, pixel_m, share)
