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

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tlessbot_ros.core.common.geometry import (
    CameraIntrinsics,
    invert_transform,
    make_transform,
    rotation_about_axis,
)
from tlessbot_ros.core.common.rig import CameraMount, Rig
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
        aruco = _aruco()
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
        return points @ T[:3, :3].T + T[:3, 3]

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
        return self.cv_board().generateImage((width + 2 * margin_px, height + 2 * margin_px),
                                             marginSize=margin_px, borderBits=1)


def _dictionary_size(name: str) -> int:
    aruco = _aruco()
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
    aruco = _aruco()
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
    asymmetric pattern pulls a corner by ~0.1 px (measured on synthetic views: 0.12 px rms
    against 0.06 px once refined inside the gap; the side camera's pose error fell from 1.4 to
    0.1 mm). The gap, ``(square - marker) / 2`` on the board, is measured in the image from
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


@dataclass
class BoardPose:
    """The board seen by one camera in one image.

    Attributes:
        T_camera_board: (4, 4) board frame -> camera optical frame, metres.
        rms_px: root-mean-square reprojection error of the corners kept, pixels.
        max_px: largest reprojection error of the corners kept, pixels.
        corners: corners the pose was fitted to.
        rejected: corners dropped as outliers (e.g. refined onto the edge of a part).
        sigma_mm: one standard deviation of the camera centre (relative to the board) along
            its worst direction, from the residuals (first-order propagation), mm.
        sigma_deg: the same for the camera's orientation, degrees.
    """

    T_camera_board: np.ndarray
    rms_px: float
    max_px: float
    corners: int
    rejected: int
    sigma_mm: float = float('nan')
    sigma_deg: float = float('nan')


def _camera_arrays(intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    """K (3, 3) and OpenCV distortion coefficients (empty when all are zero, whatever the model
    is called: realsense-ros names the D415's zero colour distortion in several ways)."""
    D = np.asarray(intrinsics.D, np.float64).ravel()
    if not np.any(D):
        return np.asarray(intrinsics.K, np.float64), np.zeros(0)
    if intrinsics.distortion_model not in ('plumb_bob', 'rational_polynomial'):
        raise CalibrationError(
            f'distortion model {intrinsics.distortion_model!r} is not supported by the board '
            "calibration; give a 'plumb_bob' or 'rational_polynomial' CameraInfo (rectify "
            'fisheye images first)')
    return np.asarray(intrinsics.K, np.float64), D


def _aruco() -> Any:
    """OpenCV's aruco module, with the ChArUco API of OpenCV 4.7 and later."""
    import cv2

    if not hasattr(cv2, 'aruco') or not hasattr(cv2.aruco, 'CharucoDetector'):
        raise CalibrationError(
            f'the board calibration needs OpenCV 4.7 or later with the aruco module '
            f'(cv2.aruco.CharucoDetector); this is OpenCV {cv2.__version__}: '
            "pip install 'opencv-python-headless>=4.8'")
    return cv2.aruco


def _reprojection(points: np.ndarray, pixels: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
                  K: np.ndarray, D: np.ndarray) -> np.ndarray:
    import cv2

    projected, _ = cv2.projectPoints(points, rvec, tvec, K, D)
    return np.linalg.norm(projected.reshape(-1, 2) - pixels, axis=1)


def fit_board_pose(points: np.ndarray, pixels: np.ndarray, intrinsics: CameraIntrinsics, *,
                   initial: np.ndarray | None = None, min_corners: int = 6,
                   outlier_px: float = 2.0) -> BoardPose:
    """``T_camera_board`` from board points and their pixels by planar PnP.

    Without ``initial``, IPPE gives the (up to two) poses of the plane and the one with the
    smaller reprojection error is kept. Corners farther than ``outlier_px`` (or 3x the median
    error, if larger) from its reprojection are dropped, and Levenberg-Marquardt refines the
    pose on the rest (``cv2.solvePnPRefineLM``), twice. The intrinsics' distortion
    coefficients are used (the D415's colour stream has nearly none).

    Args:
        points: (N, 3) board-frame corner positions, metres, z = 0 (the same corner may come
            several times, from several images of a camera and board that did not move).
        pixels: (N, 2) their image positions, pixels.
        intrinsics: the images' intrinsics (from their CameraInfo).
        initial: (4, 4) a ``T_camera_board`` to start from instead of IPPE.
        min_corners: fewest corners a pose is computed from (at least 4).
        outlier_px: reprojection error beyond which a corner is an outlier, pixels.

    Raises:
        CalibrationError: fewer than ``min_corners`` corners agree with one pose.
    """
    import cv2

    min_corners = max(int(min_corners), 4)
    points = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    pixels = np.ascontiguousarray(pixels, np.float64).reshape(-1, 2)
    K, D = _camera_arrays(intrinsics)
    if len(points) < min_corners:
        raise CalibrationError(f'{len(points)} corners, {min_corners} needed for a pose')
    if initial is None:
        _, rvecs, tvecs, errors = cv2.solvePnPGeneric(points, pixels, K, D,
                                                      flags=cv2.SOLVEPNP_IPPE)
        best = int(np.argmin(np.asarray(errors).ravel()))
        rvec, tvec = rvecs[best].copy(), tvecs[best].copy()
    else:
        rvec = cv2.Rodrigues(np.asarray(initial, np.float64)[:3, :3])[0]
        tvec = np.asarray(initial, np.float64)[:3, 3].reshape(3, 1).copy()
    keep = np.ones(len(points), bool)
    for _ in range(2):
        residual = _reprojection(points, pixels, rvec, tvec, K, D)
        keep = residual <= max(outlier_px, 3.0 * float(np.median(residual[keep])))
        if keep.sum() < min_corners:
            raise CalibrationError(
                f'only {int(keep.sum())} of {len(points)} corners agree with one pose within '
                f'{outlier_px} px, {min_corners} needed')
        rvec, tvec = cv2.solvePnPRefineLM(points[keep], pixels[keep], K, D, rvec, tvec)
    residual = _reprojection(points[keep], pixels[keep], rvec, tvec, K, D)
    rms = float(np.sqrt(np.mean(residual ** 2)))
    R, _ = cv2.Rodrigues(rvec)
    sigma_mm, sigma_deg = _pose_uncertainty(points[keep], rvec, tvec, K, D, rms)
    return BoardPose(T_camera_board=make_transform(R, tvec.ravel()), rms_px=rms,
                     max_px=float(residual.max()), corners=int(keep.sum()),
                     rejected=int((~keep).sum()), sigma_mm=sigma_mm, sigma_deg=sigma_deg)


def _pose_uncertainty(points: np.ndarray, rvec: np.ndarray, tvec: np.ndarray, K: np.ndarray,
                      D: np.ndarray, rms_px: float) -> tuple[float, float]:
    """(mm, deg): the largest standard deviation of the camera centre and of its orientation,
    for pixel errors of ``rms_px`` per corner: covariance ``s^2 (J^T J)^-1`` of the pose
    parameters (Gauss-Newton at the solution; s^2 per image coordinate, with the 6 degrees of
    freedom taken out), propagated to the centre ``-R^T t`` by a numeric Jacobian."""
    import cv2

    _, jacobian = cv2.projectPoints(points, rvec, tvec, K, D)
    J = jacobian[:, :6]
    dof = max(2 * len(points) - 6, 1)
    variance = (rms_px ** 2) * 2 * len(points) / (2.0 * dof)
    try:
        covariance = variance * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return float('inf'), float('inf')

    def centre(params: np.ndarray) -> np.ndarray:
        R, _ = cv2.Rodrigues(params[:3])
        return -R.T @ params[3:]

    x0 = np.concatenate([np.ravel(rvec), np.ravel(tvec)])
    step = 1e-6
    C = np.column_stack([(centre(x0 + step * e) - centre(x0 - step * e)) / (2 * step)
                         for e in np.eye(6)])
    centre_cov = C @ covariance @ C.T
    sigma_m = float(np.sqrt(max(np.linalg.eigvalsh(centre_cov).max(), 0.0)))
    sigma_rad = float(np.sqrt(max(np.linalg.eigvalsh(covariance[:3, :3]).max(), 0.0)))
    return 1000.0 * sigma_m, float(np.degrees(sigma_rad))


def board_pose(detection: BoardDetection, board: BoardSpec, intrinsics: CameraIntrinsics, *,
               min_corners: int = 6, outlier_px: float = 2.0) -> BoardPose:
    """``T_camera_board`` of one image's detected corners (:func:`fit_board_pose`).

    Raises:
        CalibrationError: fewer than ``min_corners`` corners found (the board is not seen,
            too small, blurred or hidden), or fewer that agree with one pose.
    """
    if len(detection) < max(int(min_corners), 4):
        raise CalibrationError(_not_seen(detection, board, min_corners))
    try:
        return fit_board_pose(board.corner_points(detection.ids), detection.corners_px,
                              intrinsics, min_corners=min_corners, outlier_px=outlier_px)
    except CalibrationError as error:
        raise CalibrationError(f'the board is not seen well: {error}') from None


def camera_pose_from_board(image: np.ndarray, board: BoardSpec, intrinsics: CameraIntrinsics,
                           *, T_world_board: np.ndarray | None = None,
                           min_corners: int = 6) -> tuple[np.ndarray, BoardPose]:
    """``T_world_camera`` (4, 4) of the camera that took ``image``, and the board's pose in it.

    ``T_world_board`` places the board on the table (:func:`board_on_table`; default identity:
    the board is the world).

    Raises:
        CalibrationError: the board is not seen (:func:`board_pose`).
    """
    pose = board_pose(detect_board(image, board), board, intrinsics, min_corners=min_corners)
    T_world_board = np.eye(4) if T_world_board is None else np.asarray(T_world_board, float)
    return T_world_board @ invert_transform(pose.T_camera_board), pose


@dataclass
class CameraCalibration:
    """One camera's pose from the board over several images.

    Attributes:
        name: camera name.
        T_world_camera: (4, 4) the camera's pose, or None if no image gave one.
        images: images offered.
        seen: images that showed at least ``min_corners`` corners.
        used: images with corners in the fit.
        corners: corners of the fit (counted once per image), after dropping outliers.
        rejected: corners dropped as outliers.
        rms_px: reprojection error of the fit, pixels (root mean square).
        worst_image_px: the largest per-image RMS reprojection error under the fitted pose
            (a board that moved between images shows here), pixels.
        sigma_mm, sigma_deg: the fit's standard deviations (:class:`BoardPose`).
        failures: why images were left out (one message per distinct reason).
        intrinsics: the intrinsics of the last image offered.
    """

    name: str
    T_world_camera: np.ndarray | None
    images: int = 0
    seen: int = 0
    used: int = 0
    corners: int = 0
    rejected: int = 0
    rms_px: float = float('nan')
    worst_image_px: float = float('nan')
    sigma_mm: float = float('nan')
    sigma_deg: float = float('nan')
    failures: list[str] = field(default_factory=list)
    intrinsics: CameraIntrinsics | None = None


def calibrate_camera(name: str, images: Iterable[tuple[np.ndarray, CameraIntrinsics]],
                     board: BoardSpec, *, T_world_board: np.ndarray | None = None,
                     min_corners: int = 6, outlier_px: float = 2.0) -> CameraCalibration:
    """One fixed camera's ``T_world_camera`` from its images of the board lying still.

    The camera and the board do not move, so the corners of all images are observations of
    one pose, fitted together (:func:`fit_board_pose` on their union, each image's corners
    counted): images that each see part of the board (parts hiding different corners in
    different frames) add up to all of it, where a pose per image and their mean would be as
    poor as the poorest part view (from 1.1 m, 8 corners of one half of the default board give
    a pose 5 cm and 3 degrees off). Corners that do not agree with the fit (refined onto a
    part's edge, or from an image in which the board had moved) are dropped. Images with other
    intrinsics than the last are left out.

    Args:
        name: the camera's name, for the report.
        images: (H, W, 3) uint8 RGB (or (H, W) grey) images with their intrinsics.
        board: the board on the table.
        T_world_board: (4, 4) where it lies (:func:`board_on_table`; default identity).
        min_corners, outlier_px: see :func:`fit_board_pose`.

    Returns:
        The :class:`CameraCalibration`; its ``T_world_camera`` is None when the board was not
        seen (``failures`` says why).
    """
    import cv2

    detections, intrinsics_seen = [], []
    for image, intrinsics in images:
        detections.append(detect_board(image, board))
        intrinsics_seen.append(intrinsics)
    report = CameraCalibration(name, None, images=len(detections),
                               intrinsics=intrinsics_seen[-1] if intrinsics_seen else None)
    if not detections:
        report.failures.append('no images')
        return report
    last = intrinsics_seen[-1]
    chosen = []
    for k, (detection, intrinsics) in enumerate(zip(detections, intrinsics_seen)):
        if not _same_intrinsics(intrinsics, last):
            _note(report, 'images with other intrinsics than the last were left out')
        elif len(detection):
            chosen.append(k)
        if len(detection) < min_corners:
            _note(report, _not_seen(detection, board, min_corners))
    report.seen = sum(len(d) >= min_corners for d in detections)
    if not chosen:
        return report
    points = np.concatenate([board.corner_points(detections[k].ids) for k in chosen])
    pixels = np.concatenate([detections[k].corners_px for k in chosen])
    image_of = np.concatenate([np.full(len(detections[k]), k) for k in chosen])
    K, D = _camera_arrays(last)
    initial = _consensus_start(points, pixels, image_of, K, D, min_corners=min_corners,
                               outlier_px=outlier_px)
    try:
        fit = fit_board_pose(points, pixels, last, initial=initial, min_corners=min_corners,
                             outlier_px=outlier_px)
    except CalibrationError as error:
        _note(report, f'all images together: {error}')
        return report
    rvec = cv2.Rodrigues(fit.T_camera_board[:3, :3])[0]
    residual = _reprojection(points, pixels, rvec, fit.T_camera_board[:3, 3], K, D)
    T_world_board = np.eye(4) if T_world_board is None else np.asarray(T_world_board, float)
    report.T_world_camera = T_world_board @ invert_transform(fit.T_camera_board)
    report.used = len(chosen)
    report.corners, report.rejected, report.rms_px = fit.corners, fit.rejected, fit.rms_px
    report.worst_image_px = max(float(np.sqrt(np.mean(residual[image_of == k] ** 2)))
                                for k in chosen)
    report.sigma_mm, report.sigma_deg = fit.sigma_mm, fit.sigma_deg
    return report


def _consensus_start(points: np.ndarray, pixels: np.ndarray, image_of: np.ndarray,
                     K: np.ndarray, D: np.ndarray, *, min_corners: int,
                     outlier_px: float) -> np.ndarray | None:
    """A ``T_camera_board`` to start the joint fit from: of the IPPE poses of all corners
    together and of each image alone, the one most corners agree with (within
    ``outlier_px``), as RANSAC with images as the samples. The poses of all corners alone would
    be a compromise between a board that moved and where it was, with no corner left out."""
    import cv2

    candidates = [np.ones(len(points), bool)]
    candidates += [image_of == k for k in np.unique(image_of)
                   if np.count_nonzero(image_of == k) >= max(min_corners, 4)]
    best, best_score = None, (-1, 0.0)
    for subset in candidates:
        if np.count_nonzero(subset) < 4:
            continue
        _, rvecs, tvecs, _ = cv2.solvePnPGeneric(points[subset], pixels[subset], K, D,
                                                 flags=cv2.SOLVEPNP_IPPE)
        for rvec, tvec in zip(rvecs, tvecs):
            residual = _reprojection(points, pixels, rvec, tvec, K, D)
            score = (int(np.count_nonzero(residual <= outlier_px)), -float(np.median(residual)))
            if score > best_score:
                R, _ = cv2.Rodrigues(rvec)
                best, best_score = make_transform(R, np.ravel(tvec)), score
    return best


def _note(report: CameraCalibration, message: str) -> None:
    if message not in report.failures:
        report.failures.append(message)


def _not_seen(detection: BoardDetection, board: BoardSpec, min_corners: int) -> str:
    return (f'the board is not seen: {len(detection)} of its {board.corner_count} corners found '
            f'({detection.markers} markers), {max(int(min_corners), 4)} needed; check that the '
            'board in the image is the one described (squares, dictionary), flat, lit and in '
            'view')


def _same_intrinsics(a: CameraIntrinsics, b: CameraIntrinsics) -> bool:
    return ((a.width, a.height) == (b.width, b.height) and np.allclose(a.K, b.K)
            and a.D.shape == b.D.shape and np.allclose(a.D, b.D))


def calibrate_rig(images: Mapping[str, Iterable[tuple[np.ndarray, CameraIntrinsics]]],
                  board: BoardSpec, *, T_world_board: np.ndarray | None = None,
                  world_frame: str = 'world', min_corners: int = 6
                  ) -> tuple[Rig, dict[str, CameraCalibration]]:
    """The rig measured from each camera's images of one board lying still on the table.

    Args:
        images: camera name -> its (image, intrinsics) pairs; each camera's last intrinsics
            are the rig's.
        board: the board on the table.
        T_world_board: where it lies (:func:`board_on_table`); default: the board is the world.
        world_frame: the rig's world frame name.
        min_corners: see :func:`board_pose`.

    Returns:
        The rig, and per camera its :class:`CameraCalibration`.

    Raises:
        CalibrationError: a camera saw the board in none of its images (the message gives
            that camera's reasons).
    """
    cameras, reports = {}, {}
    for name, pairs in images.items():
        report = calibrate_camera(name, pairs, board, T_world_board=T_world_board,
                                  min_corners=min_corners)
        reports[name] = report
        if report.T_world_camera is None:
            reasons = '; '.join(report.failures) or 'no images'
            raise CalibrationError(f'camera {name!r}: no pose from the board in '
                                   f'{report.images} image(s): {reasons}')
        assert report.intrinsics is not None  # set whenever a pose was found
        cameras[name] = CameraMount(name, report.intrinsics, report.T_world_camera)
    return Rig(cameras=cameras, world_frame=world_frame), reports
