"""The rig from a bag of a ChArUco board lying on the table (``tlessbot calibrate --board``).

Each camera's colour images and CameraInfo are read from the bag (``/NAME/color/image_raw``,
``/NAME/color/camera_info`` for every camera of the prior rig), each image gives the camera's
pose from the board, and the poses are averaged (:mod:`tlessbot_ros.core.calibrate.board`).
The result is a rig in the cell YAML's look-at form, and a report of how well the board was
seen and how far the prior rig (config/cell.yaml) was from it.

The board options (``--board-*``) are shared with ``tlessbot simulate --board`` and
``tlessbot board``: the same flags describe the same print.
"""
from __future__ import annotations

import argparse
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tlessbot_ros.core.calibrate import BoardSpec, CameraCalibration, board_on_table
from tlessbot_ros.core.common import Rig, rotation_angle_deg
from tlessbot_ros.errors import CalibrationError, TlessbotError

DEFAULT_MAX_FRAMES = 30


def add_board_arguments(parser: argparse.ArgumentParser) -> None:
    """The ``--board-*`` options describing the print and where it lies on the table."""
    spec = BoardSpec()
    parser.add_argument('--board-squares', type=int, nargs=2, metavar=('X', 'Y'),
                        default=[spec.squares_x, spec.squares_y],
                        help="squares along the board's rows and columns (default "
                             f'{spec.squares_x} {spec.squares_y})')
    parser.add_argument('--board-square-m', type=float, default=spec.square_length_m,
                        help='side of a square as printed, metres (default '
                             f'{spec.square_length_m}: 7 x 5 fits A3)')
    parser.add_argument('--board-marker-m', type=float, default=spec.marker_length_m,
                        help=f'side of a marker as printed, metres (default '
                             f'{spec.marker_length_m})')
    parser.add_argument('--board-dictionary', default=spec.dictionary,
                        help=f'OpenCV ArUco dictionary (default {spec.dictionary})')
    parser.add_argument('--board-pose', type=float, nargs=3, metavar=('X_M', 'Y_M', 'YAW_DEG'),
                        default=[0.0, 0.0, 0.0],
                        help='where the board lies in the world: its centre on the table and '
                             'the turn of its rows from world x (default 0 0 0: the board '
                             'defines the world, x along its rows, z up)')


def board_from_args(args: argparse.Namespace) -> BoardSpec:
    """The :class:`BoardSpec` of the ``--board-*`` options (a user error as TlessbotError)."""
    try:
        return BoardSpec(squares_x=args.board_squares[0], squares_y=args.board_squares[1],
                         square_length_m=args.board_square_m,
                         marker_length_m=args.board_marker_m, dictionary=args.board_dictionary)
    except ValueError as error:
        raise TlessbotError(f'board: {error}') from None


def board_pose_from_args(args: argparse.Namespace) -> np.ndarray:
    """(4, 4) ``T_world_board`` of ``--board-pose``."""
    return board_on_table(*args.board_pose)


@dataclass
class BoardCalibrationReport:
    """What a board calibration saw and how far the prior rig was from its result.

    Attributes:
        cameras: per camera name its :class:`CameraCalibration`.
        prior_offset: per camera (position mm, rotation deg) of the prior rig from the result.
        prior_pair_offset: the same for the transform between the first two cameras (e.g.
            top <-> side), or None with fewer cameras.
        pair: the names of those two cameras.
        ms_per_image: wall time per image (decoding, detection, pose), milliseconds.
    """

    cameras: dict[str, CameraCalibration]
    prior_offset: dict[str, tuple[float, float]] = field(default_factory=dict)
    prior_pair_offset: tuple[float, float] | None = None
    pair: tuple[str, str] | None = None
    ms_per_image: float = float('nan')


def pose_offset(T_a: np.ndarray, T_b: np.ndarray) -> tuple[float, float]:
    """(distance between the translations in mm, rotation angle in degrees) of two (4, 4)
    transforms."""
    return (1000.0 * float(np.linalg.norm(T_a[:3, 3] - T_b[:3, 3])),
            rotation_angle_deg(T_a[:3, :3], T_b[:3, :3]))


def rig_offsets(rig: Rig, reference: Rig) -> tuple[dict[str, tuple[float, float]],
                                                   tuple[float, float] | None]:
    """Per camera of ``rig`` its (mm, deg) from ``reference``, and the same for the transform
    between the rig's first two cameras (None with fewer)."""
    per_camera = {name: pose_offset(cam.T_world_camera, reference[name].T_world_camera)
                  for name, cam in rig.cameras.items() if name in reference.cameras}
    names = list(rig.cameras)
    if len(names) < 2 or not all(n in reference.cameras for n in names[:2]):
        return per_camera, None
    a, b = names[:2]
    return per_camera, pose_offset(rig.T_a_b(a, b), reference.T_a_b(a, b))


def read_colour_frames(bag: Path, cameras: list[str], *, max_frames: int = DEFAULT_MAX_FRAMES
                       ) -> dict[str, list[tuple[np.ndarray, Any]]]:
    """Per camera up to ``max_frames`` (RGB (H, W, 3) uint8, CameraIntrinsics) pairs from a
    bag's ``/NAME/color/image_raw`` and ``/NAME/color/camera_info``; each image takes the
    camera's latest CameraInfo (or the first one, for images before it).

    Raises:
        BagError: unreadable bag or missing topics.
        CalibrationError: a camera without CameraInfo, or with an unusable one.
    """
    from tlessbot_ros.conversions import camera_info_to_intrinsics
    from tlessbot_ros.conversions.image import image_to_rgb
    from tlessbot_ros.conversions.topics import COLOR, COLOR_INFO, camera_topic
    from tlessbot_ros.io.bags import deserialize, read_bag

    topics = {}
    for name in cameras:
        topics[camera_topic(name, COLOR)] = (name, 'image')
        topics[camera_topic(name, COLOR_INFO)] = (name, 'info')
    images: dict[str, list[Any]] = {name: [] for name in cameras}
    pending: dict[str, list[Any]] = {name: [] for name in cameras}
    info: dict[str, Any] = {}
    for message in read_bag(bag, list(topics)):
        name, kind = topics[message.topic]
        if kind == 'info':
            msg = deserialize(message)
            try:
                info[name] = camera_info_to_intrinsics(msg)
            except ValueError as error:
                raise CalibrationError(f'{message.topic}: {error}') from None
        elif len(images[name]) + len(pending[name]) < max_frames:
            rgb = image_to_rgb(deserialize(message))
            if name in info:
                images[name].append((rgb, info[name]))
            else:
                pending[name].append(rgb)
        if name in info and pending[name]:
            images[name] = [(rgb, info[name]) for rgb in pending[name]] + images[name]
            pending[name] = []
    for name in cameras:
        if name not in info:
            raise CalibrationError(f'bag {bag} has no CameraInfo on '
                                   f'{camera_topic(name, COLOR_INFO)}')
    return images


def calibrate_with_board(bag_path: Path, rig_prior: Rig, board: BoardSpec, *,
                         T_world_board: np.ndarray | None = None,
                         max_frames: int = DEFAULT_MAX_FRAMES
                         ) -> tuple[Rig, BoardCalibrationReport]:
    """The rig from a bag of ``board`` lying still on the table, seen by every camera of
    ``rig_prior`` (whose names say which topics to read, and which it is compared with).

    Args:
        bag_path: rosbag2 folder or .mcap file.
        rig_prior: the rig to compare with (config/cell.yaml); its cameras are calibrated.
        board: the print.
        T_world_board: (4, 4) where the board lies (default identity: it defines the world).
        max_frames: images used per camera (the first ones).

    Raises:
        BagError: unreadable bag or missing topics.
        CalibrationError: a camera did not see the board in any image.
    """
    from tlessbot_ros.core.calibrate import calibrate_rig

    cameras = list(rig_prior.cameras)
    frames = read_colour_frames(Path(bag_path), cameras, max_frames=max_frames)
    start = time.perf_counter()
    rig, reports = calibrate_rig(frames, board, T_world_board=T_world_board,
                                 world_frame=rig_prior.world_frame)
    count = sum(len(v) for v in frames.values())
    per_camera, pair = rig_offsets(rig, rig_prior)
    return rig, BoardCalibrationReport(
        cameras=reports, prior_offset=per_camera, prior_pair_offset=pair,
        pair=(cameras[0], cameras[1]) if len(cameras) >= 2 else None,
        ms_per_image=1000.0 * (time.perf_counter() - start) / max(count, 1))


def format_report(report: BoardCalibrationReport) -> str:
    """Human-readable lines of a :class:`BoardCalibrationReport` (pure)."""
    lines = []
    for name, cam in report.cameras.items():
        lines.append(
            f'{name}: {cam.used} of {cam.images} images fitted together ({cam.corners} corners, '
            f'{cam.rejected} dropped, {cam.rms_px:.3f} px rms, worst image '
            f'{cam.worst_image_px:.3f} px); 1 sigma {cam.sigma_mm:.1f} mm, '
            f'{cam.sigma_deg:.2f} deg')
        if name in report.prior_offset:
            mm, deg = report.prior_offset[name]
            lines.append(f'{name}: the prior rig is {mm:.1f} mm and {deg:.2f} deg from it')
    if report.pair is not None and report.prior_pair_offset is not None:
        mm, deg = report.prior_pair_offset
        lines.append(f'{report.pair[0]} <-> {report.pair[1]}: the prior is {mm:.1f} mm and '
                     f'{deg:.2f} deg from it')
    lines.append(f'{report.ms_per_image:.0f} ms per image')
    return '\n'.join(lines)


def add_calibrate_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``tlessbot calibrate --board`` besides ``--board-*``."""
    parser.add_argument('--bag', type=Path, required=True,
                        help='bag with /NAME/color/image_raw and /NAME/color/camera_info of the '
                             'board lying still on the table')
    parser.add_argument('--config', type=Path,
                        help='cell YAML with the prior rig (default config/cell.yaml)')
    parser.add_argument('--out', type=Path, help='write the cell YAML with the measured rig here')
    parser.add_argument('--max-frames', type=int, default=DEFAULT_MAX_FRAMES,
                        help=f'images used per camera (default {DEFAULT_MAX_FRAMES})')
    add_board_arguments(parser)


def run_board_calibration(args: argparse.Namespace) -> int:
    """``tlessbot calibrate --board``: needs ``args.bag``, ``args.config``, ``args.out``,
    ``args.max_frames`` and the ``--board-*`` options."""
    from tlessbot_ros.io.config import default_config_path
    from tlessbot_ros.tools.support.rig import load_rig, write_rig

    if args.max_frames < 1:
        raise TlessbotError('--max-frames must be at least 1')
    board = board_from_args(args)
    config = args.config or default_config_path()
    prior = load_rig(config)
    rig, report = calibrate_with_board(args.bag, prior, board,
                                       T_world_board=board_pose_from_args(args),
                                       max_frames=args.max_frames)
    print(format_report(report))
    if args.out is not None:
        write_rig(config, rig, args.out,
                  note='measured from a ChArUco board (tlessbot calibrate --board)')
        print(f'wrote {args.out}')
    return 0
