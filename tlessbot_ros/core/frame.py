"""What one frame of the perception pipeline (:mod:`tlessbot_ros.core.pipeline`) takes and
gives: a view's input, the class of an instance, a found part, a frame's result, and one part's
pose fit as a job that a :class:`PartFitter` may run elsewhere."""
from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from tlessbot_ros.core.common import CameraIntrinsics, TableFrame
from tlessbot_ros.core.localise import BackgroundModel
from tlessbot_ros.core.pose import ImageBox, PoseCandidate


@dataclass
class ViewInput:
    """One camera's data for one frame.

    Attributes:
        rgb: (H, W, 3) uint8 RGB.
        depth_m: (H, W) float32 aligned depth in metres, NaN or 0 = invalid (None if absent).
        intrinsics: colour intrinsics (aligned depth shares them).
        T_world_camera: (4, 4) camera pose in the table frame (world z = 0 is the table), or
            None when uncalibrated (then the table plane seen in the depth gives the frame,
            see ``FitParams.table_plane``).
        background: empty-table image of this camera (for background subtraction), or None.
    """

    rgb: np.ndarray
    depth_m: np.ndarray | None
    intrinsics: CameraIntrinsics
    T_world_camera: np.ndarray | None = None
    background: BackgroundModel | np.ndarray | None = None


@dataclass(frozen=True)
class ClassGuess:
    """Class of one instance: object id (0 = unknown), score and margin (summed over the views
    that see it), its preferred view, and the classes for the pose stage to verify, best first
    (``candidates[0] == obj_id``; ``obj_id`` alone when the classifier is sure of a part seen
    only from the top, see ``top_view_verify_below_margin``; empty when unknown)."""

    obj_id: int
    score: float
    margin: float
    view: str | None
    candidates: tuple[int, ...] = ()


@dataclass
class Detection:
    """One found part.

    Attributes:
        instance_id: id in the label images.
        obj_id: recognised class (0 = unknown).
        view: camera whose data gave the pose (its optical frame holds ``T_camera_object``).
        box: (x, y, w, h) in that view.
        class_score, class_margin: classifier outputs.
        class_rank: rank of ``obj_id`` among the classifier's candidates (0 = its first
            choice; more when the pose fit overruled it).
        pose, second: best and second-best pose candidates (None when not estimated).
        n_points: ROI points used.
        turned_over: the flat parts' orientation check turned the fitted pose over (its
            former pose is ``second``).
    """

    instance_id: int
    obj_id: int
    view: str
    box: tuple[int, int, int, int]
    class_score: float = 0.0
    class_margin: float = 0.0
    class_rank: int = 0
    pose: PoseCandidate | None = None
    second: PoseCandidate | None = None
    n_points: int = 0
    turned_over: bool = False


@dataclass
class FrameResult:
    """Detections of one frame, the label images, per-stage wall times (ms) and the table
    frame each view was read in (with the rig's difference from the observed plane)."""

    detections: list[Detection]
    labels: dict[str, np.ndarray]
    timings_ms: dict[str, float] = field(default_factory=dict)
    tables: dict[str, TableFrame] = field(default_factory=dict)


@dataclass
class PartJob:
    """One part to fit: its detection (filled in by the fit), its ROI cloud ((N, 3) metres in
    the optical frame of ``detection.view``), its class candidates best first, and that
    view's table frame ``T_world_camera`` (:meth:`PerceptionPipeline.table_frame`; None: no
    table frame, the pose stage's fallback). ``more_views``: for a part whose candidates have
    a look-alike, its ROI clouds in the other cameras, each as ((M, 3) points in that
    camera's optical frame, (4, 4) ``T_other_camera``), for the look-alike check
    (:meth:`PerceptionPipeline.check_lookalike`; the fit does not use them). ``box_camera``: in box
    mode, the (3, 3) camera matrix of ``detection.view``: the detection's box is then the part's
    given box, which the fit's poses must cover (``FitParams.box_cover``); None: no box."""

    detection: Detection
    points: np.ndarray
    candidates: tuple[int, ...]
    T_world_camera: np.ndarray | None
    more_views: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    box_camera: np.ndarray | None = None

    @property
    def box(self) -> ImageBox | None:
        """The part's given box (box mode, ``box_camera``), else None."""
        return None if self.box_camera is None else ImageBox(self.detection.box, self.box_camera)


class PartFitter(Protocol):
    """Runs the fits of one frame's parts, e.g. several at once (``tlessbot_ros.parallel``)."""

    def fit_all(self, jobs: Sequence[PartJob], fit_here: Callable[[PartJob], None],
                on_done: Callable[[PartJob], None]) -> None:
        """Fit every job (``fit_here`` fits one in this process) and call ``on_done`` once per
        job as soon as it is fitted, never from two threads at once."""


__all__ = ['ClassGuess', 'Detection', 'FrameResult', 'PartFitter', 'PartJob', 'ViewInput']
