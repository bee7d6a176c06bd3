"""The board's pose seen by one camera in one image: planar PnP on the identified corners
(IPPE, Collins and Bartoli, IJCV 109, 2014), outliers dropped, and its first-order uncertainty
(Hartley and Zisserman, 2nd ed., §5.2). Frames as in :mod:`.board`."""
from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from tlessbot_ros.core.calibrate.board import (
    BoardDetection,
    BoardSpec,
    detect_board,
    not_seen_message,
)
from tlessbot_ros.core.common.geometry import (
    CameraIntrinsics,
    invert_transform,
    make_transform,
)
from tlessbot_ros.errors import CalibrationError


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


def camera_arrays(intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray]:
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


def reprojection_px(points: np.ndarray, pixels: np.ndarray, rvec: np.ndarray, tvec: np.ndarray,
                  K: np.ndarray, D: np.ndarray) -> np.ndarray:
    import cv2

    projected, _ = cv2.projectPoints(points, rvec, tvec, K, D)
    return cast(np.ndarray, np.linalg.norm(projected.reshape(-1, 2) - pixels, axis=1))


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
    K, D = camera_arrays(intrinsics)
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
        residual = reprojection_px(points, pixels, rvec, tvec, K, D)
        keep = residual <= max(outlier_px, 3.0 * float(np.median(residual[keep])))
        if keep.sum() < min_corners:
            raise CalibrationError(
                f'only {int(keep.sum())} of {len(points)} corners agree with one pose within '
                f'{outlier_px} px, {min_corners} needed')
        rvec, tvec = cv2.solvePnPRefineLM(points[keep], pixels[keep], K, D, rvec, tvec)
    residual = reprojection_px(points[keep], pixels[keep], rvec, tvec, K, D)
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
        return cast(np.ndarray, -R.T @ params[3:])

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
        raise CalibrationError(not_seen_message(detection, board, min_corners))
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

