"""The rig from what the two cameras see: table planes and the parts both views show.

Each camera sees the table in its depth (:func:`~tlessbot_ros.core.common.find_table_plane`),
which fixes its tilt and its height over the table. What no single view fixes is where the two
cameras stand relative to each other *in* the table plane: a turn about the table normal and a
shift along the table (three numbers, :mod:`.inplane`). The parts on the table fix those: both
cameras see the same parts, and the points above the table of one view, moved by the right
in-plane transform, lie on the surfaces the other view sees.

:class:`SceneCalibrator` accumulates cheap per-frame observations and solves occasionally:

1. *Observation* (:func:`observe_view`, docs/bench/rig-calibration.md for its cost): every few
   pixels of the aligned depth (about ``point_spacing_m`` apart on the table), those above the
   table by more than the depth noise are part points, grouped into blobs by connected
   components in the image. Each frame keeps per view its plane, its part points (camera
   frame) and their blob.
2. *Planes*: the median plane of each view over the frames kept, the camera levelled on it
   about its own centre (:func:`~.inplane.level_camera_on_plane`), so each view's points get
   heights over the table and x, y near the prior's.
3. *Coarse in-plane fit*: per blob, the x, y of its upper part and its height; hypotheses from
   one or two blob pairs of one frame (within the prior's gate: ``prior_max_yaw_deg``,
   ``prior_max_shift_m``), each scored on every frame by mutual nearest blobs within
   ``match_distance_m`` (MSAC, Torr & Zisserman, CVIU 2000); the best refitted on its
   matches (:func:`~.inplane.procrustes_2d`).
4. *Fine in-plane fit*: ICP (Besl & McKay, PAMI 1992) of the side view's part points onto the
   top view's, frame by frame, over the three in-plane degrees of freedom, the pair distance
   shrinking to ``icp_distance_m``: visible-surface centroids differ between views by up to a
   part's size; the surfaces themselves agree to the depth noise.

The gauge: the scene cannot tell where the world origin lies on the table nor which way its x
axis points. Both are kept from the prior's top camera (its position in the plane and its
heading); everything else (both tilts and heights, the side camera's position and heading
relative to the top camera) comes from the scene. Compare rigs with :func:`rig_errors`, which
does not depend on the gauge.
"""
from __future__ import annotations

import time
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from tlessbot_ros.core.calibrate.comparison import RigDifference, rig_differences
from tlessbot_ros.core.calibrate.inplane import inplane_parameters, level_camera_on_plane
from tlessbot_ros.core.calibrate.inplane_fit import (
    coarse_fit,
    fine_fit,
    median_plane,
    world_view,
)
from tlessbot_ros.core.calibrate.observation import (
    FrameObservation,
    ViewObservation,
    observe_view,
    view_stride_px,
)
from tlessbot_ros.core.calibrate.params import SceneCalibrationParams
from tlessbot_ros.core.common.rig import SIDE, TOP, Rig
from tlessbot_ros.core.common.table_plane import TablePlane, find_table_plane, plane_of_frame


@dataclass(frozen=True)
class RigEstimate:
    """The rig the scene shows, and how far to trust it.

    Attributes:
        rig: the estimated rig (the prior's intrinsics; world yaw and origin from the prior's
            top camera).
        prior: the rig it was estimated against (config/cell.yaml).
        levelled: the prior's cameras levelled on the tables they see (tilt and height from
            the scene, in-plane placement from the prior).
        in_plane: (yaw_deg, x_m, y_m) of the in-plane correction applied to the side camera.
        planes: frames whose table was found in both views (in the plane history).
        frames: frames kept with parts in both views; frames_matched: those with a part
            matched between the views; matches: matched blobs in all.
        pairs: point pairs of the fine fit's last iteration.
        residual_m: their RMS distance in the plane.
        overlap: share of the side view's part points within ``icp_distance_m`` of the top
            view's; prior_overlap: the same with the prior's in-plane placement (planes
            levelled): the prior explains the scene this well.
        yaw_sigma_deg, shift_sigma_m: uncertainty of the in-plane fit (spread of the per-frame
            fits over the square root of their number; inf with fewer than two).
        in_plane_solved: whether the parts gave an in-plane fit (else only the planes are
            used: the prior's in-plane placement is kept).
        confident: the in-plane fit meets every threshold of the parameters.
        differences: :func:`rig_differences` of ``rig`` from ``prior``.
        solve_ms: time of the solve.
    """

    rig: Rig
    prior: Rig
    levelled: Rig
    in_plane: tuple[float, float, float] = (0.0, 0.0, 0.0)
    planes: int = 0
    frames: int = 0
    frames_matched: int = 0
    matches: int = 0
    pairs: int = 0
    residual_m: float = float('nan')
    overlap: float = 0.0
    prior_overlap: float = 0.0
    yaw_sigma_deg: float = float('inf')
    shift_sigma_m: float = float('inf')
    in_plane_solved: bool = False
    confident: bool = False
    differences: dict[str, RigDifference] = field(default_factory=dict)
    solve_ms: float = 0.0

    def summary(self) -> str:
        """One line: what the estimate rests on and how far it is from the prior."""
        parts = [f'{self.planes} frames with both tables, {self.frames} with parts in both '
                 f'views, {self.frames_matched} matched, {self.matches} matched parts']
        if self.in_plane_solved:
            parts.append(f'fit residual {1e3 * self.residual_m:.1f} mm, overlap '
                         f'{self.overlap:.2f} (config: {self.prior_overlap:.2f}), sigma '
                         f'{self.yaw_sigma_deg:.2f} deg / {1e3 * self.shift_sigma_m:.1f} mm')
        parts.append('confident' if self.confident else
                     'in-plane from the config' if not self.in_plane_solved else 'not confident')
        return '; '.join(parts)


# --------------------------------------------------------------------------- calibrator
class SceneCalibrator:
    """Accumulates frames of a fixed two-camera rig and estimates the rig from them.

    Args:
        prior: the rig as configured (its intrinsics are used unless a frame gives its own;
            its extrinsics say which plane is the table and fix the gauge).
        params: see :class:`SceneCalibrationParams`.
        top, side: the camera names in ``prior``.

    Example:
        >>> calibrator = SceneCalibrator(rig)
        >>> for depth in frames:                    # {'top': (H, W), 'side': (H, W)} metres
        ...     calibrator.add_frame(depth)
        >>> estimate = calibrator.solve()
        >>> estimate.rig, estimate.confident
    """

    def __init__(self, prior: Rig, *, params: SceneCalibrationParams = SceneCalibrationParams(),
                 top: str = TOP, side: str = SIDE) -> None:
        self.prior = prior
        self.params = params
        self.names = (top, side)
        self.frames: deque[FrameObservation] = deque(maxlen=params.max_frames)
        self.planes: dict[str, deque[np.ndarray]] = {
            name: deque(maxlen=params.plane_history) for name in self.names}
        self.resets = 0
        self.added = 0                 # frames offered
        self._jumps = {name: 0 for name in self.names}
        self._rng = np.random.default_rng(params.seed)

    def clear(self) -> None:
        """Forget every observation (the cameras moved, or a new prior)."""
        self.frames.clear()
        for history in self.planes.values():
            history.clear()

    # ------------------------------------------------------------------- observing
    def add_frame(self, depth_m: Mapping[str, np.ndarray | None], *,
                  K: Mapping[str, np.ndarray] | None = None,
                  planes: Mapping[str, TablePlane | np.ndarray | None] | None = None,
                  parts: bool = True) -> FrameObservation:
        """Observe one frame.

        Args:
            depth_m: per camera name, (H, W) aligned depth in metres (None: not seen).
            K: per camera name, (3, 3) camera matrix (default: the prior's intrinsics).
            planes: per camera name, its table plane if already found (e.g. by the
                pipeline's table frame), else it is found here (``params.plane``, the prior's
                plane as a guide).
            parts: False: only the planes are taken (no part points; the frame is not
                kept).

        Returns:
            the frame's :class:`FrameObservation` (the views whose table was found); it is
            kept when both views show parts.
        """
        self.added += 1
        views = {}
        for name in self.names:
            depth = depth_m.get(name)
            if depth is None:
                continue
            K_view = np.asarray(K[name] if K and name in K else
                                self.prior[name].intrinsics.K, np.float64)
            plane = None if planes is None else planes.get(name)
            if isinstance(plane, TablePlane):
                plane = plane.plane
            if plane is None:
                found = find_table_plane(
                    depth, K_view, params=self.params.plane,
                    prior=plane_of_frame(self.prior[name].T_world_camera))
                plane = None if found is None else found.plane
            if plane is None or not self._accept_plane(name, np.asarray(plane, np.float64)):
                continue
            if not parts:
                views[name] = ViewObservation.plane_only(plane)
                continue
            stride = view_stride_px(K_view, self.prior[name].T_world_camera,
                                    self.params.point_spacing_m)
            views[name] = observe_view(depth, K_view, plane, stride_px=stride,
                                       params=self.params, rng=self._rng)
        frame = FrameObservation(views, self.added - 1)
        if len(views) == len(self.names):
            for name, view in views.items():
                self.planes[name].append(view.plane)
            if frame.has_parts(self.names):
                self.frames.append(frame)
        return frame

    def _accept_plane(self, name: str, plane: np.ndarray) -> bool:
        """False for a plane far from the view's history (an outlier, or the first frame
        after the camera moved); the second such frame running starts everything again."""
        history = self.planes[name]
        if not history:
            return True
        median = median_plane(history)
        angle = np.degrees(np.arccos(np.clip(median[:3] @ plane[:3], -1.0, 1.0)))
        if angle <= self.params.reset_angle_deg and \
                abs(plane[3] - median[3]) <= self.params.reset_offset_m:
            self._jumps[name] = 0
            return True
        self._jumps[name] += 1
        if self._jumps[name] < 2:
            return False
        self.clear()
        self.resets += 1
        self._jumps = {n: 0 for n in self.names}
        return True

    # ------------------------------------------------------------------- solving
    def solve(self) -> RigEstimate | None:
        """The rig the frames kept so far show (None before both tables were seen)."""
        t0 = time.perf_counter()
        top, side = self.names
        if not self.planes[top] or not self.planes[side]:
            return None
        levelled = {name: level_camera_on_plane(self.prior[name].T_world_camera,
                                                median_plane(self.planes[name]))
                    for name in self.names}
        world = [{name: world_view(frame.views[name], levelled[name]) for name in self.names}
                 for frame in self.frames]
        coarse = coarse_fit(world, self.params, top, side) if world else None
        fine = None if coarse is None else fine_fit(world, coarse, self.params, top, side)
        G = np.eye(4) if fine is None else fine.G
        rig = self._rig({top: levelled[top], side: G @ levelled[side]})
        yaw, x, y = inplane_parameters(G)
        p = self.params
        estimate = RigEstimate(rig, self.prior, self._rig(levelled),
                               (float(np.degrees(yaw)), x, y),
                               planes=min(len(self.planes[top]), len(self.planes[side])),
                               frames=len(self.frames))
        if coarse is not None and fine is not None:
            estimate = replace(
                estimate, frames_matched=coarse.frames_matched, matches=coarse.matches,
                pairs=fine.pairs, residual_m=fine.residual_m, overlap=fine.overlap,
                prior_overlap=fine.prior_overlap, yaw_sigma_deg=fine.yaw_sigma_deg,
                shift_sigma_m=fine.shift_sigma_m, in_plane_solved=True)
            estimate = replace(estimate, confident=bool(
                estimate.frames_matched >= p.min_frames and estimate.matches >= p.min_matches
                and estimate.yaw_sigma_deg <= p.max_yaw_sigma_deg
                and estimate.shift_sigma_m <= p.max_shift_sigma_m
                and estimate.overlap >= p.min_overlap))
        return replace(estimate, differences=rig_differences(self.prior, rig, top=top,
                                                             side=side),
                       solve_ms=1e3 * (time.perf_counter() - t0))


    def _rig(self, poses: Mapping[str, np.ndarray]) -> Rig:
        """The prior with the cameras of ``poses`` (name: T_world_camera) moved."""
        return Rig(cameras={name: replace(mount, T_world_camera=poses[name])
                            if name in poses else mount
                            for name, mount in self.prior.cameras.items()},
                   world_frame=self.prior.world_frame)


__all__ = ['RigEstimate', 'SceneCalibrator']
