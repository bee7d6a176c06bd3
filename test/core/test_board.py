"""The ChArUco board calibration on synthetic views rendered here by ray casting (independent of
the simulator's renderer): known poses come back, with and without lens distortion."""
import functools

import cv2
import numpy as np
import pytest

from tlessbot_ros.core.calibrate import (
    BoardDetection,
    BoardSpec,
    board_on_table,
    board_pose,
    calibrate_camera,
    calibrate_rig,
    camera_pose_from_board,
    detect_board,
)
from tlessbot_ros.core.common import (
    CameraIntrinsics,
    default_rig,
    invert_transform,
    look_at,
    rotation_angle_deg,
)
from tlessbot_ros.errors import CalibrationError

BOARD = BoardSpec()
PX_PER_M = 4000.0  # board texture: 0.25 mm a texel


def render_board(board, intrinsics, T_camera_board, *, seed=0, noise=1.0):
    """(H, W, 3) uint8 view of the board lying on a grey table (:func:`_albedo`), with an sRGB
    gamma and seeded noise of ``noise`` grey levels."""
    albedo = _albedo(board, intrinsics.width, intrinsics.height, intrinsics.K.tobytes(),
                     intrinsics.D.tobytes(), np.asarray(T_camera_board, float).tobytes())
    grey = 255.0 * np.clip(1.1 * albedo, 0, 1) ** (1 / 2.2)
    grey += np.random.default_rng(seed).normal(0.0, noise, grey.shape)
    return np.repeat(np.clip(np.rint(grey), 0, 255).astype(np.uint8)[..., None], 3, axis=2)


@functools.lru_cache(maxsize=8)
def _albedo(board, w, h, K_bytes, D_bytes, T_bytes, supersample=3):
    """(H, W) float32 albedo: each pixel averages supersample^2 rays cast through the lens
    distortion onto the board plane (a sensor's pixel integrates its area, so edges come out
    anti-aliased); paper 0.8, ink 0.04, table 0.3."""
    K, D = np.frombuffer(K_bytes).reshape(3, 3), np.frombuffer(D_bytes)
    T = invert_transform(np.frombuffer(T_bytes).reshape(4, 4))  # camera -> board
    margin = int(0.01 * PX_PER_M)
    texture = np.where(board.image(PX_PER_M, margin_px=margin) > 127, 0.8, 0.04)
    texture = texture.astype(np.float32)
    th, tw = texture.shape
    s = supersample
    u, v = np.meshgrid((np.arange(w * s) + 0.5) / s - 0.5, (np.arange(h * s) + 0.5) / s - 0.5)
    pixels = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    if np.any(D):
        rays = cv2.undistortPointsIter(pixels, K, D, None, None, (
            cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)).reshape(-1, 2)
    else:
        rays = (pixels.reshape(-1, 2) - K[:2, 2]) / [K[0, 0], K[1, 1]]
    dirs = np.column_stack([rays, np.ones(len(rays))]) @ T[:3, :3].T
    reach = -T[2, 3] / dirs[:, 2]
    xy = T[:2, 3] + reach[:, None] * dirs[:, :2]
    map_x = (xy[:, 0] * PX_PER_M + (tw - 1) / 2).astype(np.float32).reshape(h * s, w * s)
    map_y = (-xy[:, 1] * PX_PER_M + (th - 1) / 2).astype(np.float32).reshape(h * s, w * s)
    albedo = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                       borderValue=0.3)
    albedo[(reach <= 0).reshape(h * s, w * s)] = 0.3
    return albedo.reshape(h, s, w, s).mean(axis=(1, 3))


def _errors(T_a, T_b):
    return 1000 * np.linalg.norm(T_a[:3, 3] - T_b[:3, 3]), rotation_angle_deg(T_a, T_b)


def _intrinsics(D=None):
    K = np.array([[615.0, 0, 319.5], [0, 615.0, 239.5], [0, 0, 1]])
    return CameraIntrinsics(640, 480, K, D=np.zeros(5) if D is None else np.asarray(D))


# An oblique view from 0.65 m (as the side camera) and a steeper one from 0.8 m.
VIEWS = {
    'oblique': look_at([0.03, -0.25, 0.60], [0.01, 0.02, 0.0], [0.0, 0.0, 1.0]),
    'steep': look_at([-0.12, 0.10, 0.78], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
}
# A lens with some distortion (the D415's colour stream reports nearly none).
DISTORTION = [0.06, -0.15, 0.001, -0.001, 0.08]


@pytest.mark.parametrize('distorted', [False, True])
def test_pose_of_a_rendered_board(distorted):
    intrinsics = _intrinsics(DISTORTION if distorted else None)
    T_world_camera = VIEWS['oblique']
    image = render_board(BOARD, intrinsics, invert_transform(T_world_camera))
    detection = detect_board(image, BOARD)
    assert len(detection) == BOARD.corner_count
    T, fit = camera_pose_from_board(image, BOARD, intrinsics)
    mm, deg = _errors(T, T_world_camera)
    assert mm < 1.0 and deg < 0.1, (mm, deg)
    assert fit.rms_px < 0.2 and fit.rejected == 0


def test_pose_uncertainty_covers_the_error():
    # Seen more squarely from farther away, the pose is less certain (corners move less when
    # the board tilts); the fit's own standard deviation says so, and covers the error.
    intrinsics = _intrinsics()
    T_world_camera = VIEWS['steep']
    for seed in range(2):
        image = render_board(BOARD, intrinsics, invert_transform(T_world_camera), seed=seed)
        T, fit = camera_pose_from_board(image, BOARD, intrinsics)
        mm, deg = _errors(T, T_world_camera)
        assert 0.3 < fit.sigma_mm < 2.0 and fit.sigma_deg < 0.2
        assert mm < 3 * fit.sigma_mm and deg < 3 * fit.sigma_deg, (mm, deg, fit)


def test_a_moved_board_gives_the_same_camera_pose():
    # Invariance: put the board elsewhere on the table and say where; the camera stays put.
    intrinsics = _intrinsics()
    T_world_camera = VIEWS['oblique']
    T_world_board = board_on_table(0.04, -0.03, 25.0)
    image = render_board(BOARD, intrinsics, invert_transform(T_world_camera) @ T_world_board)
    T, _ = camera_pose_from_board(image, BOARD, intrinsics, T_world_board=T_world_board)
    mm, deg = _errors(T, T_world_camera)
    assert mm < 1.0 and deg < 0.1, (mm, deg)
    # Without the board's pose the world is the board: the camera comes out moved with it.
    T_board, _ = camera_pose_from_board(image, BOARD, intrinsics)
    assert _errors(T_world_board @ T_board, T_world_camera)[0] < 1.0


def test_board_frame():
    corners = BOARD.corner_points()
    assert corners.shape == (BOARD.corner_count, 3) and np.all(corners[:, 2] == 0)
    assert np.allclose(corners.mean(axis=0), 0.0)  # origin at the centre of the squares
    # Corner 0 is the printed image's top-left inner corner: -x, +y in the board frame.
    assert np.allclose(corners[0], [-2.5 * 0.055, 1.5 * 0.055, 0.0])
    # The corners found in the printed image lie where the board frame says.
    image = BOARD.image(2000.0, margin_px=40)
    detection = detect_board(image, BOARD)
    points = BOARD.corner_points(detection.ids)
    h, w = image.shape
    expected = np.column_stack([points[:, 0] * 2000 + (w - 1) / 2,
                                -points[:, 1] * 2000 + (h - 1) / 2])
    assert len(detection) == BOARD.corner_count
    assert np.abs(detection.corners_px - expected).max() < 0.05


def test_board_spec_validation():
    with pytest.raises(ValueError, match='smaller than square_length_m'):
        BoardSpec(marker_length_m=0.06)
    with pytest.raises(ValueError, match='unknown ArUco dictionary'):
        BoardSpec(dictionary='DICT_9X9_1')
    with pytest.raises(ValueError, match='DICT_4X4_100'):
        BoardSpec(squares_x=12, squares_y=10)
    assert BoardSpec().size_m == pytest.approx((0.385, 0.275))


def test_a_board_not_seen_is_a_clear_error():
    intrinsics = _intrinsics()
    blank = np.full((480, 640, 3), 128, np.uint8)
    assert len(detect_board(blank, BOARD)) == 0
    with pytest.raises(CalibrationError, match=r'board is not seen: 0 of its 24 corners'):
        camera_pose_from_board(blank, BOARD, intrinsics)
    # A different board (other dictionary) on the table is not this one.
    other = BoardSpec(dictionary='DICT_5X5_50')
    image = render_board(other, intrinsics, invert_transform(VIEWS['oblique']))
    with pytest.raises(CalibrationError, match='not seen'):
        camera_pose_from_board(image, BOARD, intrinsics)
    with pytest.raises(CalibrationError, match=r"camera 'side': no pose from the board in 2"):
        calibrate_rig({'side': [(blank, intrinsics)] * 2}, BOARD)
    report = calibrate_camera('side', [(blank, intrinsics)], BOARD)
    assert report.T_world_camera is None and report.images == 1
    assert 'not seen' in report.failures[0]


def test_too_few_corners():
    detection = BoardDetection(np.zeros((3, 2)), np.arange(3), markers=2)
    with pytest.raises(CalibrationError, match='3 of its 24 corners found'):
        board_pose(detection, BOARD, _intrinsics())


def test_calibrate_rig_joins_partial_views():
    # Each image hides a different half of the board: no image alone shows all corners, the
    # joint fit sees them all and the rig comes back.
    intrinsics = _intrinsics()
    rig = default_rig()
    images = {}
    for name in ('top', 'side'):
        T_world_camera = rig[name].T_world_camera
        full = render_board(BOARD, intrinsics, invert_transform(T_world_camera), seed=1)
        half = full.shape[1] // 2
        left, right = full.copy(), full.copy()
        left[:, half:] = 77
        right[:, :half] = 77
        images[name] = [(left, intrinsics), (right, intrinsics)]
    measured, reports = calibrate_rig(images, BOARD)
    for name in ('top', 'side'):
        report = reports[name]
        assert report.used == 2 and report.seen == 2
        mm, deg = _errors(measured[name].T_world_camera, rig[name].T_world_camera)
        # The top camera looks straight down from 1.1 m: a tilt moves its corners least.
        assert mm < 3.0 and deg < 0.2, (name, mm, deg)
    mm, deg = _errors(measured.T_a_b('top', 'side'), rig.T_a_b('top', 'side'))
    assert mm < 3.0 and deg < 0.2


def test_an_image_of_a_moved_board_is_outvoted():
    # Two images of the board in place and one after it was pushed 3 cm: the corners of the
    # odd image are dropped and the pose stays that of the first two.
    intrinsics = _intrinsics()
    T_world_camera = VIEWS['oblique']
    T_camera_board = invert_transform(T_world_camera)
    images = [(render_board(BOARD, intrinsics, T_camera_board, seed=k), intrinsics)
              for k in range(2)]
    pushed = T_camera_board @ board_on_table(0.03, 0.0, 0.0)
    images.append((render_board(BOARD, intrinsics, pushed, seed=2), intrinsics))
    report = calibrate_camera('side', images, BOARD)
    assert report.used == 3 and report.rejected == BOARD.corner_count
    assert report.worst_image_px > 10.0
    mm, deg = _errors(report.T_world_camera, T_world_camera)
    assert mm < 1.0 and deg < 0.1, (mm, deg)
    # The fit's own uncertainty is of the size of its error.
    assert 0.01 < report.sigma_mm < 1.0 and report.sigma_deg < 0.1
