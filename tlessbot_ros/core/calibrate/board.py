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
Hartley et al., "Rotation averaging", IJCV 103, 2013 (the chordal mean over frames).

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

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tlessbot_ros.core.common.geometry import (
    CameraIntrinsics,
    invert_transform,
    make_transform,
    rotation_about_axis,
    rotation_angle_deg,
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
    sees each marker 22 px wide, 3.7 px per marker bit. Smaller boards lose markers there: an
    A4 board of 40 mm squares with 30 mm markers (16 px, 2.7 px a bit) lost 1 to 6 of its 24
    corners in the top view of a synthetic D415 image (blur 0.6 px, noise 1.5 grey levels),
    none in the side view (docs/bench/board-calibration.md).

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
        import cv2

        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square_length_m,
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
    import cv2

    if not name.startswith('DICT_') or not hasattr(cv2.aruco, name):
        known = sorted(n for n in dir(cv2.aruco) if n.startswith('DICT_'))
        raise ValueError(f'unknown ArUco dictionary {name!r}; choose one of {known}')
    return int(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)).bytesList.shape[0])


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
    markers = cv2.aruco.DetectorParameters()
    # Read each marker bit from 8 x 8 samples of the unwarped marker (default 4 x 4), ignoring
    # the outer 30 % of each cell (default 13 %): markers ~20 px wide, as the top camera sees
    # the default board, then decode through the blur of a real lens (17 of 17 markers instead
    # of 10 on a synthetic view with 0.8 px of blur).
    markers.perspectiveRemovePixelPerCell = 8
    markers.perspectiveRemoveIgnoredMarginPerCell = 0.3
    detector = cv2.aruco.CharucoDetector(board.cv_board(), cv2.aruco.CharucoParameters(),
                                         markers)
    corners, ids, _, marker_ids = detector.detectBoard(np.ascontiguousarray(grey))
    markers = 0 if marker_ids is None else len(marker_ids)
    if ids is None or len(ids) == 0:
        return BoardDetection(np.zeros((0, 2)), np.zeros(0, np.int64), markers)
    return BoardDetection(np.asarray(corners, np.float64).reshape(-1, 2),
                          np.asarray(ids, np.int64).ravel(), markers)


@dataclass
class BoardPose:
    """The board seen by one camera in one image.

    Attributes:
        T_camera_board: (4, 4) board frame -> camera optical frame, metres.
        rms_px: root-mean-square reprojection error of the corners kept, pixels.
        max_px: largest reprojection error of the corners kept, pixels.
        corners: corners the pose was fitted to.
        rejected: corners dropped as outliers (e.g. refined onto the edge of a part).
    """

    T_camera_board: np.ndarray
    rms_px: float
    max_px: float
    corners: int
    rejected: int


def _camera_arrays(intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
    if intrinsics.distortion_model not in ('plumb_bob', 'rational_polynomial', ''):
        raise CalibrationError(
            f'distortion model {intrinsics.distortion_model!r} is not supported by the board '
            "calibration; give a 'plumb_bob' or 'rational_polynomial' CameraInfo (rectify "
            'fisheye images first)')
    D = np.asarray(intrinsics.D, np.float64).ravel()
    if D.size and not np.any(D):
        D = np.zeros(0)
    return np.asarray(intrinsics.K, np.float64), D


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
    R, _ = cv2.Rodrigues(rvec)
    return BoardPose(T_camera_board=make_transform(R, tvec.ravel()),
                     rms_px=float(np.sqrt(np.mean(residual ** 2))),
                     max_px=float(residual.max()), corners=int(keep.sum()),
                     rejected=int((~keep).sum()))


def board_pose(detection: BoardDetection, board: BoardSpec, intrinsics: CameraIntrinsics, *,
               min_corners: int = 6, outlier_px: float = 2.0) -> BoardPose:
    """``T_camera_board`` of one image's detected corners (:func:`fit_board_pose`).

    Raises:
        CalibrationError: fewer than ``min_corners`` corners found (the board is not seen,
            too small, blurred or hidden), or fewer that agree with one pose.
    """
    min_corners = max(int(min_corners), 4)
    if len(detection) < min_corners:
        raise CalibrationError(
            f'the board is not seen: {len(detection)} of its {board.corner_count} corners found '
            f'({detection.markers} markers), {min_corners} needed; check that the board in the '
            'image is the one described (squares, dictionary), flat, lit and in view')
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


def mean_rotation(rotations: Sequence[np.ndarray]) -> np.ndarray:
    """(3, 3) chordal L2 mean of (3, 3) rotations: the rotation nearest (Frobenius) to their
    arithmetic mean (Hartley et al. 2013, §5.3); exact for rotations a few degrees apart."""
    U, _, Vt = np.linalg.svd(np.mean(np.asarray(rotations, np.float64), axis=0))
    S = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ S @ Vt


def average_transforms(transforms: Sequence[np.ndarray], *, max_offset_m: float = 0.01,
                       max_angle_deg: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A robust mean of (4, 4) rigid transforms that should agree (one camera over frames).

    The medoid (the transform nearest to all others, a centimetre counting as a degree) is the
    reference; those within ``max_offset_m`` and ``max_angle_deg`` of it are averaged
    (translations by their mean, rotations by :func:`mean_rotation`), so that a frame whose
    board pose went wrong cannot pull the result.

    Returns:
        (4, 4) mean transform and (N,) bool: the transforms averaged.
    """
    Ts = np.asarray(transforms, np.float64).reshape(-1, 4, 4)
    if len(Ts) == 0:
        raise ValueError('average_transforms needs at least one transform')
    offsets = np.linalg.norm(Ts[:, None, :3, 3] - Ts[None, :, :3, 3], axis=2)
    angles = np.array([[rotation_angle_deg(a[:3, :3], b[:3, :3]) for b in Ts] for a in Ts])
    medoid = int(np.argmin((offsets / 0.01 + angles).sum(axis=1)))
    inliers = (offsets[medoid] <= max_offset_m) & (angles[medoid] <= max_angle_deg)
    mean = make_transform(mean_rotation(Ts[inliers, :3, :3]), Ts[inliers, :3, 3].mean(axis=0))
    return mean, inliers


@dataclass
class CameraCalibration:
    """One camera's pose from the board over several images.

    Attributes:
        name: camera name.
        T_world_camera: (4, 4) the camera's pose, or None if no image gave one.
        images: images offered.
        seen: images in which the board gave a pose of its own.
        used: images whose corners went into the joint fit.
        corners: corners of the joint fit (all images), after dropping outliers.
        rms_px: reprojection error of the joint fit, pixels (root mean square).
        spread_mm: largest distance of a single image's camera centre from the result, mm.
        spread_deg: largest angle of a single image's pose from the result, degrees.
        failures: why images gave no pose of their own (one message per distinct reason).
        intrinsics: the intrinsics of the last image offered.
    """

    name: str
    T_world_camera: np.ndarray | None
    images: int = 0
    seen: int = 0
    used: int = 0
    corners: int = 0
    rms_px: float = float('nan')
    spread_mm: float = float('nan')
    spread_deg: float = float('nan')
    failures: list[str] = field(default_factory=list)
    intrinsics: CameraIntrinsics | None = None


def calibrate_camera(name: str, images: Iterable[tuple[np.ndarray, CameraIntrinsics]],
                     board: BoardSpec, *, T_world_board: np.ndarray | None = None,
                     min_corners: int = 6, outlier_px: float = 2.0,
                     max_offset_m: float = 0.01, max_angle_deg: float = 1.0
                     ) -> CameraCalibration:
    """One fixed camera's ``T_world_camera`` from its images of the board lying still.

    The camera and the board do not move, so every image's corners are observations of one
    pose: each image with enough corners gives a pose of its own (:func:`board_pose`), the
    robust mean of those (:func:`average_transforms`) says which images agree, and one pose is
    fitted to the corners of all those images together (:func:`fit_board_pose`), also of
    images that saw too few corners for a pose of their own (parts hiding the board differ
    from image to image, so together they show it all). Images with other intrinsics than the
    last are left out.

    Args:
        name: the camera's name, for the report.
        images: (H, W, 3) uint8 RGB (or (H, W) grey) images with their intrinsics.
        board: the board on the table.
        T_world_board: (4, 4) where it lies (:func:`board_on_table`; default identity).
        min_corners, outlier_px: see :func:`fit_board_pose`.
        max_offset_m, max_angle_deg: how far an image's own pose may be from the others' to
            count (:func:`average_transforms`).

    Returns:
        The :class:`CameraCalibration`; its ``T_world_camera`` is None when no image showed
        the board (``failures`` says why).
    """
    T_world_board = np.eye(4) if T_world_board is None else np.asarray(T_world_board, float)
    detections, intrinsics_seen, failures = [], [], []
    for image, intrinsics in images:
        detections.append(detect_board(image, board))
        intrinsics_seen.append(intrinsics)
    report = CameraCalibration(name, None, images=len(detections), failures=failures,
                               intrinsics=intrinsics_seen[-1] if intrinsics_seen else None)
    if not detections:
        failures.append('no images')
        return report
    last = report.intrinsics
    own = {}
    for k, (detection, intrinsics) in enumerate(zip(detections, intrinsics_seen)):
        if not _same_intrinsics(intrinsics, last):
            continue
        try:
            own[k] = board_pose(detection, board, intrinsics, min_corners=min_corners,
                                outlier_px=outlier_px).T_camera_board
        except CalibrationError as error:
            if str(error) not in failures:
                failures.append(str(error))
    if not own:
        return report
    mean, agree = average_transforms(list(own.values()), max_offset_m=max_offset_m,
                                     max_angle_deg=max_angle_deg)
    rejected = {k for k, ok in zip(own, agree) if not ok}
    chosen = [k for k, d in enumerate(detections)
              if k not in rejected and len(d) and _same_intrinsics(intrinsics_seen[k], last)]
    points = np.concatenate([board.corner_points(detections[k].ids) for k in chosen])
    pixels = np.concatenate([detections[k].corners_px for k in chosen])
    fit = fit_board_pose(points, pixels, last, initial=mean, min_corners=min_corners,
                         outlier_px=outlier_px)
    T_world_camera = T_world_board @ invert_transform(fit.T_camera_board)
    singles = [T_world_board @ invert_transform(own[k]) for k in own if k not in rejected]
    report.T_world_camera = T_world_camera
    report.seen, report.used = len(own), len(chosen)
    report.corners, report.rms_px = fit.corners, fit.rms_px
    report.spread_mm = 1000.0 * max(float(np.linalg.norm(T[:3, 3] - T_world_camera[:3, 3]))
                                    for T in singles)
    report.spread_deg = max(rotation_angle_deg(T[:3, :3], T_world_camera[:3, :3])
                            for T in singles)
    return report


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
