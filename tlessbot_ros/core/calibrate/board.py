"""The rig measured from a printed ChArUco board lying on the table (a one-off calibration).

A ChArUco board is a chessboard whose white squares hold ArUco markers: the markers say which
corner is which, so a board partly hidden (by a part, by the image border) still gives
identified corners, and the chessboard corners are located to a fraction of a pixel. Each
camera's pose over the table follows from one image: the corners' known positions on the board
and their pixels give ``T_camera_board`` (planar PnP), and the board's known place on the table
gives ``T_world_camera``. References: Garrido-Jurado et al., "Automatic generation and
detection of highly reliable fiducial markers under occlusion", Pattern Recognition 47(6),
2014 (ArUco); OpenCV's ``aruco`` module (``CharucoBoard``, ``CharucoDetector``); Collins and
Bartoli, "Infinitesimal plane-based pose estimation", IJCV 109, 2014 (IPPE, the planar PnP);
Hartley and Zisserman, "Multiple view geometry", 2nd ed., 2004, §5.2 (covariance of the
estimate).

Frames:

* the **board frame**: origin at the centre of the board's squares, x along the printed image's
  rows (to its right), y towards the printed image's top, z out of the printed face. A board
  lying face up on the table thus has z up, as the world has.
* OpenCV's object frame of the same board has its origin at the printed image's top-left
  corner, x to the right, y down and z into the face: :data:`T_BOARD_OPENCV` maps it into the
  board frame.
* ``T_world_board`` places the board on the table. The default (identity) makes the board the
  world: its centre the origin, x along its rows, z up. :func:`board_on_table` gives the pose
  of a board put elsewhere (a known offset and turn on the table).

Images are (H, W, 3) uint8 RGB or (H, W) uint8 grey; pixels and intrinsics follow OpenCV
(pixel centres at integer coordinates, K in pixels, distortion ``k1 k2 p1 p2 [k3 ...]``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, cast

import numpy as np

from tlessbot_ros.core.common.geometry import (
    make_transform,
    rotation_about_axis,
)
from tlessbot_ros.errors import CalibrationError

# OpenCV's object frame (origin top-left, y down, z into the face) -> the board frame (origin
# at the centre, y up, z out of the face); the translation to the centre is added per board.
_FLIP = np.diag([1.0, -1.0, -1.0])


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board as printed.

    The default is 7 x 5 squares of 55 mm with 40 mm markers of ``DICT_4X4_50``: 385 x 275 mm,
    which an A3 sheet (420 x 297 mm) holds with a margin. Both cameras of the paper's cell see
    all of it on the middle of the table (the top camera's 640x480 view covers 1.14 x 0.86 m
    at 1.10 m, the side camera's about 0.6 x 0.5 m), and the top camera, the farther one, still
    sees each marker 22 px wide, 3.7 px per marker bit. Smaller boards lose markers there: in
    five simulated frames of the cell, an A4 board of 40 mm squares with 30 mm markers (16 px,
    2.7 px a bit) showed the top camera 78 of its 120 corners, for a pose of 1 sigma 2.4 mm and
    0.14 degrees; the default showed all 120, for 0.8 mm and 0.04 degrees
    (docs/bench/board-calibration.md). The larger squares also leave a wider white gap around
    each corner to refine it in.

    Attributes:
        squares_x: squares along the board's rows (its printed width).
        squares_y: squares along its columns (its printed height).
        square_length_m: side of one chessboard square, metres (measure the print).
        marker_length_m: side of one ArUco marker inside a white square, metres.
        dictionary: name of an OpenCV predefined ArUco dictionary (``cv2.aruco.DICT_*``).
    """

    squares_x: int = 7
    squares_y: int = 5
    square_length_m: float = 0.055
    marker_length_m: float = 0.040
    dictionary: str = 'DICT_4X4_50'

    def __post_init__(self) -> None:
        if self.squares_x < 2 or self.squares_y < 2:
            raise ValueError(f'a ChArUco board needs at least 2 x 2 squares, got '
                             f'{self.squares_x} x {self.squares_y}')
        if not 0.0 < self.marker_length_m < self.square_length_m:
            raise ValueError(f'marker_length_m must be positive and smaller than '
                             f'square_length_m ({self.square_length_m}), got '
                             f'{self.marker_length_m}')
        size = _dictionary_size(self.dictionary)
        if size < self.marker_count:
            raise ValueError(f'{self.dictionary} has {size} markers but a {self.squares_x} x '
                             f'{self.squares_y} board needs {self.marker_count}; choose a '
                             'larger dictionary (e.g. DICT_4X4_100)')

    @property
    def marker_count(self) -> int:
        """Markers on the board (one per white square)."""
        return self.squares_x * self.squares_y // 2

    @property
    def corner_count(self) -> int:
        """Inner chessboard corners, the points the pose is computed from."""
        return (self.squares_x - 1) * (self.squares_y - 1)

    @property
    def size_m(self) -> tuple[float, float]:
        """(width, height) of the squares' area, metres."""
        return (self.squares_x * self.square_length_m, self.squares_y * self.square_length_m)

    def cv_board(self) -> Any:
        """The ``cv2.aruco.CharucoBoard`` of this spec."""
        aruco = aruco_module()
        dictionary = aruco.getPredefinedDictionary(getattr(aruco, self.dictionary))
        return aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_length_m,
                                  self.marker_length_m, dictionary)

    @property
    def T_board_opencv(self) -> np.ndarray:
        """(4, 4) OpenCV's object frame of this board -> the board frame (module docstring)."""
        width, height = self.size_m
        return make_transform(_FLIP, np.array([-width / 2.0, height / 2.0, 0.0]))

    def corner_points(self, ids: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) float64 board-frame positions (metres, z = 0) of the inner corners ``ids``
        (all, in id order, when None)."""
        points = np.asarray(self.cv_board().getChessboardCorners(), np.float64).reshape(-1, 3)
        if ids is not None:
            points = points[np.asarray(ids, np.int64).ravel()]
        T = self.T_board_opencv
        return cast(np.ndarray, points @ T[:3, :3].T + T[:3, 3])

    def image(self, px_per_m: float, *, margin_px: int = 0) -> np.ndarray:
        """(H, W) uint8 printable image of the board, 0 black, 255 white.

        The squares' area is ``size_m * px_per_m`` pixels (rounded), inside a white margin of
        ``margin_px`` on every side; print it at ``px_per_m * 0.0254`` dots per inch for the
        real lengths.
        """
        if px_per_m <= 0 or margin_px < 0:
            raise ValueError(f'need px_per_m > 0 and margin_px >= 0, got {px_per_m}, '
                             f'{margin_px}')
        width, height = (int(round(s * px_per_m)) for s in self.size_m)
        image: np.ndarray = self.cv_board().generateImage(
            (width + 2 * margin_px, height + 2 * margin_px), marginSize=margin_px, borderBits=1)
        return image


def _dictionary_size(name: str) -> int:
    aruco = aruco_module()
    if not name.startswith('DICT_') or not hasattr(aruco, name):
        known = sorted(n for n in dir(aruco) if n.startswith('DICT_'))
        raise ValueError(f'unknown ArUco dictionary {name!r}; choose one of {known}')
    return int(aruco.getPredefinedDictionary(getattr(aruco, name)).bytesList.shape[0])


def board_on_table(x_m: float = 0.0, y_m: float = 0.0, yaw_deg: float = 0.0) -> np.ndarray:
    """(4, 4) ``T_world_board`` of a board lying face up on the table (z = 0) with its centre
    at (``x_m``, ``y_m``) and its rows turned ``yaw_deg`` from world x (counter-clockwise seen
    from above). All zero: the board defines the world."""
    return make_transform(rotation_about_axis(np.array([0.0, 0.0, 1.0]), np.radians(yaw_deg)),
                          np.array([x_m, y_m, 0.0]))


@dataclass
class BoardDetection:
    """The board's corners found in one image.

    Attributes:
        corners_px: (N, 2) float64 sub-pixel corner positions (x right, y down).
        ids: (N,) int64 corner ids (index into :meth:`BoardSpec.corner_points`).
        markers: number of ArUco markers decoded.
    """

    corners_px: np.ndarray
    ids: np.ndarray
    markers: int

    def __len__(self) -> int:
        return int(len(self.ids))


def detect_board(image: np.ndarray, board: BoardSpec) -> BoardDetection:
    """Find the ChArUco corners of ``board`` in an (H, W, 3) uint8 RGB or (H, W) uint8 grey
    image; an empty detection when the board is not seen (never raises for that).

    The markers are decoded, the chessboard corners between them are predicted from each
    marker's local homography and refined to sub-pixel accuracy (OpenCV's ``detectBoard``).
    """
    import cv2

    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim not in (2, 3):
        raise ValueError(f'image must be (H, W) or (H, W, 3) uint8, got {image.shape} '
                         f'{image.dtype}')
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
    aruco = aruco_module()
    markers = aruco.DetectorParameters()
    # Read each marker bit from 8 x 8 samples of the unwarped marker (default 4 x 4), ignoring
    # the outer 30 % of each cell (default 13 %): markers ~20 px wide, as the top camera sees
    # the default board, then decode through the blur of a real lens (17 of 17 markers instead
    # of 10 on a synthetic view with 0.8 px of blur).
    markers.perspectiveRemovePixelPerCell = 8
    markers.perspectiveRemoveIgnoredMarginPerCell = 0.3
    detector = aruco.CharucoDetector(board.cv_board(), aruco.CharucoParameters(), markers)
    corners, ids, _, marker_ids = detector.detectBoard(np.ascontiguousarray(grey))
    markers = 0 if marker_ids is None else len(marker_ids)
    if ids is None or len(ids) == 0:
        return BoardDetection(np.zeros((0, 2)), np.zeros(0, np.int64), markers)
    corners = np.asarray(corners, np.float32).reshape(-1, 2)
    ids = np.asarray(ids, np.int64).ravel()
    half = _refine_window(corners, ids, board)
    if half:
        criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
        corners = cv2.cornerSubPix(grey, corners.reshape(-1, 1, 2).copy(), (half, half),
                                   (-1, -1), criteria).reshape(-1, 2)
    return BoardDetection(corners.astype(np.float64), ids, markers)


def _refine_window(corners: np.ndarray, ids: np.ndarray, board: BoardSpec) -> int:
    """Half-size (pixels) of a corner refinement window that stays inside the white gap
    between a corner and the markers of its two white squares, or 0 if unknown.

    OpenCV refines ChArUco corners in a window that can reach the markers' edges, whose
    asymmetric pattern pulls a corner off its place (docs/bench/board-calibration.md). The
    gap, ``(square - marker) / 2`` on the board, is measured in the image from
    the spacing of neighbouring corners (the smaller of rows and columns, for foreshortening).
    """
    per_row = board.squares_x - 1
    spacing = []
    for step in (1, per_row):
        index = {int(i): k for k, i in enumerate(ids)}
        pairs = [(index[i], index[i + step]) for i in index
                 if i + step in index and (step != 1 or (i + 1) % per_row)]
        if pairs:
            a, b = np.array(pairs).T
            spacing.append(float(np.median(np.linalg.norm(corners[a] - corners[b], axis=1))))
    if not spacing:
        return 0
    gap_px = min(spacing) * (board.square_length_m - board.marker_length_m) / (
        2.0 * board.square_length_m)
    return int(np.clip(np.floor(gap_px) - 1, 2, 6))


def aruco_module() -> Any:
    """OpenCV's aruco module, with the ChArUco API of OpenCV 4.7 and later."""
    import cv2

    if not hasattr(cv2, 'aruco') or not hasattr(cv2.aruco, 'CharucoDetector'):
        raise CalibrationError(
            f'the board calibration needs OpenCV 4.7 or later with the aruco module '
            f'(cv2.aruco.CharucoDetector); this is OpenCV {cv2.__version__}: '
            "pip install 'opencv-python-headless>=4.8'")
    return cv2.aruco


def not_seen_message(detection: BoardDetection, board: BoardSpec, min_corners: int) -> str:
    return (f'the board is not seen: {len(detection)} of its {board.corner_count} corners found '
            f'({detection.markers} markers), {max(int(min_corners), 4)} needed; check that the '
            'board in the image is the one described (squares, dictionary), flat, lit and in '
            'view')

