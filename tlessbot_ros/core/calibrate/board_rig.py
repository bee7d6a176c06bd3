"""Cameras calibrated with a ChArUco board (:mod:`.board`): the intrinsics of one camera from
images of the board in several poses, and the rig from one image per camera of the board lying
on the table."""
from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from tlessbot_ros.core.calibrate.board import BoardSpec, detect_board, not_seen_message
from tlessbot_ros.core.calibrate.board_pose import (
    camera_arrays,
    fit_board_pose,
    reprojection_px,
)
from tlessbot_ros.core.common.geometry import (
    CameraIntrinsics,
    invert_transform,
    make_transform,
)
from tlessbot_ros.core.common.rig import CameraMount, Rig
from tlessbot_ros.errors import CalibrationError


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
            _note(report, not_seen_message(detection, board, min_corners))
    report.seen = sum(len(d) >= min_corners for d in detections)
    if not chosen:
        return report
    points = np.concatenate([board.corner_points(detections[k].ids) for k in chosen])
    pixels = np.concatenate([detections[k].corners_px for k in chosen])
    image_of = np.concatenate([np.full(len(detections[k]), k) for k in chosen])
    K, D = camera_arrays(last)
    initial = _consensus_start(points, pixels, image_of, K, D, min_corners=min_corners,
                               outlier_px=outlier_px)
    try:
        fit = fit_board_pose(points, pixels, last, initial=initial, min_corners=min_corners,
                             outlier_px=outlier_px)
    except CalibrationError as error:
        _note(report, f'all images together: {error}')
        return report
    rvec = cv2.Rodrigues(fit.T_camera_board[:3, :3])[0]
    residual = reprojection_px(points, pixels, rvec, fit.T_camera_board[:3, 3], K, D)
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
            residual = reprojection_px(points, pixels, rvec, tvec, K, D)
            score = (int(np.count_nonzero(residual <= outlier_px)), -float(np.median(residual)))
            if score > best_score:
                R, _ = cv2.Rodrigues(rvec)
                best, best_score = make_transform(R, np.ravel(tvec)), score
    return best



def _note(report: CameraCalibration, message: str) -> None:
    if message not in report.failures:
        report.failures.append(message)


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
