"""A printed ChArUco board lying on the simulated table, for testing the board calibration.

The board is a :class:`~tlessbot_ros.sim.materials.Decal` of the table: the renderer samples the
table's albedo at each pixel's point on the plane z = 0, so the print appears in every camera
with exact perspective and goes through the same lighting, shadows, exposure, blur and colour
noise as the table; being flat, it leaves the depth unchanged.

The print is ``cv2.aruco``'s board image on white paper, as linear albedo (paper 0.80, toner
0.04), at 0.25 mm a texel. The renderer samples the albedo once per pixel (at its centre), so
each camera gets the print smoothed by a Gaussian of half its pixel's footprint on the board
(about 0.9 mm for the top camera, 0.5 mm for the side one): sharp squares sampled at points
alias, and their corners then moved by up to 0.1 px, enough to tilt the top camera's pose by a
few tenths of a degree. A symmetric blur leaves every chessboard corner where it is.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tlessbot_ros.core.calibrate import BoardSpec, board_on_table
from tlessbot_ros.core.common.geometry import invert_transform
from tlessbot_ros.sim.materials import Decal


@dataclass(frozen=True)
class SimBoard:
    """A board lying face up on the simulated table.

    Attributes:
        spec: the board (squares, lengths, dictionary).
        x_m, y_m, yaw_deg: its centre on the table and the turn of its rows from world x
            (:func:`~tlessbot_ros.core.calibrate.board.board_on_table`); zeros: the board's
            frame is the world's.
        margin_m: white paper around the squares.
        paper_albedo, ink_albedo: linear reflectance of the paper and of the print.
        texel_m: texture resolution, metres.
        blur_px: Gaussian smoothing of the print (anti-aliasing), in pixels of the camera
            that sees it (:meth:`decal`).
    """

    spec: BoardSpec = field(default_factory=BoardSpec)
    x_m: float = 0.0
    y_m: float = 0.0
    yaw_deg: float = 0.0
    margin_m: float = 0.01
    paper_albedo: float = 0.80
    ink_albedo: float = 0.04
    texel_m: float = 0.00025
    blur_px: float = 0.5

    def __post_init__(self) -> None:
        if self.margin_m < 0 or self.texel_m <= 0 or self.blur_px < 0:
            raise ValueError('board margin_m and blur_px must be >= 0 and texel_m > 0')
        if not 0.0 <= self.ink_albedo < self.paper_albedo <= 1.0:
            raise ValueError(f'need 0 <= ink_albedo < paper_albedo <= 1, got '
                             f'{self.ink_albedo}, {self.paper_albedo}')

    @property
    def T_world_board(self) -> np.ndarray:
        """(4, 4) board frame -> world."""
        return board_on_table(self.x_m, self.y_m, self.yaw_deg)

    def footprint_m(self, T_world_camera: np.ndarray, focal_px: float) -> float:
        """Side of one pixel of a camera (pose (4, 4), focal length in pixels) on the board's
        centre, metres."""
        distance = np.linalg.norm(np.asarray(T_world_camera)[:3, 3] - self.T_world_board[:3, 3])
        return float(distance) / float(focal_px)

    def decal(self, blur_m: float) -> Decal:
        """The print as a table decal, smoothed by a Gaussian of ``blur_m`` metres."""
        import cv2

        px_per_m = 1.0 / self.texel_m
        margin_px = int(round(self.margin_m * px_per_m))
        image = self.spec.image(px_per_m, margin_px=margin_px)
        texture = np.where(image > 127, np.float32(self.paper_albedo),
                           np.float32(self.ink_albedo)).astype(np.float32)
        if blur_m > 0:
            texture = cv2.GaussianBlur(texture, (0, 0), blur_m * px_per_m,
                                       borderType=cv2.BORDER_REPLICATE)
        h, w = texture.shape
        # Board frame (centre, x right, y up on the print) -> texel (column, row): texel
        # centres at integers, the image's centre at ((w - 1) / 2, (h - 1) / 2).
        board_to_texel = np.array([[px_per_m, 0.0, (w - 1) / 2.0],
                                   [0.0, -px_per_m, (h - 1) / 2.0]])
        T_board_world = invert_transform(self.T_world_board)
        table_to_texel = board_to_texel @ np.vstack([T_board_world[:2][:, [0, 1, 3]],
                                                     [0.0, 0.0, 1.0]])
        return Decal(np.ascontiguousarray(texture), table_to_texel)
