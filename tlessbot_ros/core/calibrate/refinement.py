"""What a running localiser does with the rig the scene shows (``rig_refinement.*``).

:class:`RigRefiner` wraps a :class:`~tlessbot_ros.core.calibrate.scene.SceneCalibrator` for a
stream of frames: it observes each frame (cheap: docs/bench/rig-calibration.md), solves when
there is something new to learn (each of the first frames that bring parts seen by both views
until the estimate is confident, then every ``solve_every_frames`` such frames), and says
which rig the two-view fusion should use and how far the configured one is from what the
cameras see.

Deterministic by design: the solve runs in the frame's own thread, before that frame is fused,
so a replay gives the same labels whatever the timing (#19); its cost is spread over the
frames (:attr:`RigRefiner.cost_ms`).
"""
from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from tlessbot_ros.core.calibrate.comparison import RigDifference, rig_differences
from tlessbot_ros.core.calibrate.params import SceneCalibrationParams
from tlessbot_ros.core.calibrate.scene import RigEstimate, SceneCalibrator
from tlessbot_ros.core.common.rig import Rig
from tlessbot_ros.core.common.table_plane import TablePlane
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput

RIG_REFINEMENT_MODES = ('none', 'report', 'use')


@dataclass(frozen=True)
class RigRefinementParams:
    """How the localiser checks and refines the configured rig from what the cameras see.

    Attributes:
        mode: 'none' (the configured rig, unchecked), 'report' (estimate it, warn on /diagnostics)
            or 'use' (fuse with it once confident).
        warn_angle_deg, warn_offset_m: /diagnostics is WARN while a camera, or the top -> side
            transform, of the configured rig differs from the estimate by more than this.
        use_min_angle_deg, use_min_offset_m: 'use': a configured rig that the scene confirms to
            within this angle, deg, and offset, m, is kept.
        solve_every_frames: the estimate is solved again after this many more frames with parts in
            both views (>= 1).
        observe_every_frames: once confident, part points are taken from every this many-th frame
            only (>= 1; the tables: every frame).
        provisional_min_overlap, provisional_overlap_gain: before confident, 'use' fuses with a fit
            that places this share of side part points on the top's (0..1), and this much more than
            the config.
        min_frames, min_matches, max_frames: confident from min_frames frames with matched parts
            and min_matches matched parts; the latest max_frames are fitted.

    ``mode`` is 'none', not 'off' (YAML reads that as false). 'report' estimates the rig from
    the table planes and the parts both views see and says on /diagnostics how far the
    configured one is from it (WARN past ``warn_angle_deg`` / ``warn_offset_m``); 'use' also
    fuses with the estimate once it is confident and differs from the configured rig by more
    than ``use_min_angle_deg`` / ``use_min_offset_m`` (before that: the configured cameras
    levelled onto the tables they see, when that differs by as much), so a right
    config/cell.yaml gives the same labels as without refinement. Before it is confident the
    estimate is solved after each of the first two ``min_frames`` frames with parts, so a
    scene that never becomes confident costs no more than a confident one. The estimator's
    settings are :class:`~tlessbot_ros.core.calibrate.params.SceneCalibrationParams`.
    """

    mode: str = 'use'
    warn_angle_deg: float = 1.0
    warn_offset_m: float = 0.01
    use_min_angle_deg: float = 0.5
    use_min_offset_m: float = 0.005
    solve_every_frames: int = 50
    observe_every_frames: int = 5
    provisional_min_overlap: float = 0.4
    provisional_overlap_gain: float = 0.2
    min_frames: int = SceneCalibrationParams.min_frames
    min_matches: int = SceneCalibrationParams.min_matches
    max_frames: int = SceneCalibrationParams.max_frames

    def __post_init__(self) -> None:
        if self.mode not in RIG_REFINEMENT_MODES:
            raise ValueError(f'mode must be one of {RIG_REFINEMENT_MODES}, got {self.mode!r}')
        if min(self.warn_angle_deg, self.warn_offset_m, self.use_min_angle_deg,
               self.use_min_offset_m) < 0:
            raise ValueError('warn_* and use_min_* must be >= 0')
        if not (0 <= self.provisional_min_overlap <= 1 and 0 <= self.provisional_overlap_gain):
            raise ValueError('provisional_min_overlap must be in [0, 1], '
                             'provisional_overlap_gain >= 0')
        if self.solve_every_frames < 1 or self.observe_every_frames < 1:
            raise ValueError(f'solve_every_frames and observe_every_frames must be >= 1, got '
                             f'{self.solve_every_frames} and {self.observe_every_frames}')
        _ = self.scene   # SceneCalibrationParams checks min_frames, min_matches, max_frames

    @property
    def scene(self) -> SceneCalibrationParams:
        """The estimator's settings."""
        return SceneCalibrationParams(min_frames=self.min_frames, min_matches=self.min_matches,
                                      max_frames=self.max_frames)


@dataclass(frozen=True)
class RefinementStatus:
    """What /diagnostics shows of the refinement.

    Attributes:
        warn: the configured rig is off by more than the warning thresholds.
        message: one line for the diagnostic status ('' when all is well).
        values: key -> text for the diagnostic status's values.
    """

    warn: bool = False
    message: str = ''
    values: dict[str, str] = field(default_factory=dict)


class RigRefiner:
    """The configured rig checked, and refined, over a stream of frames.

    Args:
        prior: the configured rig (config/cell.yaml).
        params: see :class:`RigRefinementParams`.
    """

    def __init__(self, prior: Rig, params: RigRefinementParams = RigRefinementParams()) -> None:
        self.frames = 0
        self.total_ms = 0.0           # observing and solving, all frames
        self._start(prior, params)

    def _start(self, prior: Rig, params: RigRefinementParams) -> None:
        self.params = params
        self.prior = prior
        self.calibrator = SceneCalibrator(prior, params=params.scene)
        self.estimate: RigEstimate | None = None
        self.in_use = 'config'        # or 'observed'
        self.solves = 0
        self._new_frames = 0          # frames with parts in both views since the last solve
        self._rig = prior

    @property
    def rig(self) -> Rig:
        """The rig the fusion should use now."""
        return self._rig

    @property
    def cost_ms(self) -> float:
        """Mean time per frame spent observing and solving."""
        return self.total_ms / self.frames if self.frames else 0.0

    def set_prior(self, prior: Rig) -> None:
        """A new configured rig (a parameter change): start again from it."""
        self._start(prior, self.params)

    def set_params(self, params: RigRefinementParams) -> None:
        """New settings: the observations are kept unless the estimator's settings changed."""
        if params.scene != self.params.scene:
            self._start(self.prior, params)
            return
        self.params = params
        self._choose()

    def observe(self, depth_m: Mapping[str, np.ndarray | None], *,
                K: Mapping[str, np.ndarray] | None = None,
                planes: Mapping[str, TablePlane | np.ndarray | None] | None = None) -> bool:
        """Take one frame's depth (and, if known, its table planes); solve when due.

        Returns:
            whether :attr:`rig` changed.
        """
        if self.params.mode == 'none':
            return False
        t0 = time.perf_counter()
        self.frames += 1
        resets = self.calibrator.resets
        confident = self.estimate is not None and self.estimate.confident
        parts = not confident or self.frames % self.params.observe_every_frames == 0
        frame = self.calibrator.add_frame(depth_m, K=K, planes=planes, parts=parts)
        if self.calibrator.resets != resets:   # a camera moved: what was learnt is gone
            self.estimate, self._new_frames = None, 0
        kept = bool(self.calibrator.frames) and self.calibrator.frames[-1] is frame
        self._new_frames += kept
        confident = self.estimate is not None and self.estimate.confident
        eager = not confident and len(self.calibrator.frames) <= 2 * self.params.scene.min_frames
        due = (self.estimate is None and len(frame.views) == 2) or (kept and (
            eager or self._new_frames >= self.params.solve_every_frames))
        changed = False
        if due:
            estimate = self.calibrator.solve()
            if estimate is not None:
                self.solves += 1
                self._new_frames = 0
                # a confident estimate is replaced only by another confident one
                if not confident or estimate.confident:
                    self.estimate = estimate
                changed = self._choose()
        self.total_ms += 1e3 * (time.perf_counter() - t0)
        return changed

    def _provisional(self, estimate: RigEstimate) -> bool:
        """An in-plane fit that is not confident yet but explains the scene far better than
        the configured rig (``provisional_*``)."""
        p = self.params
        return estimate.in_plane_solved and estimate.overlap >= p.provisional_min_overlap and \
            estimate.overlap >= estimate.prior_overlap + p.provisional_overlap_gain

    def _candidate(self, estimate: RigEstimate) -> tuple[Rig, dict[str, RigDifference]]:
        """The rig the scene vouches for and its differences from the configured one: the
        estimate once confident or provisional; before, the configured cameras levelled on
        their tables."""
        if estimate.confident or self._provisional(estimate):
            return estimate.rig, estimate.differences
        return estimate.levelled, rig_differences(self.prior, estimate.levelled)

    def _choose(self) -> bool:
        """Pick the rig for the fusion from the estimate and the mode; True if it changed."""
        old = self._rig
        self._rig, self.in_use = self.prior, 'config'
        candidate = None if self.estimate is None else self._candidate(self.estimate)
        if self.params.mode == 'use' and candidate is not None and any(
                d.exceeds(self.params.use_min_angle_deg, self.params.use_min_offset_m)
                for d in candidate[1].values()):
            self._rig, self.in_use = candidate[0], 'observed'
        return self._rig is not old

    def status(self) -> RefinementStatus:
        """/diagnostics content: state, confidence, the configured rig's difference, cost."""
        p = self.params
        values = {'rig_refinement': p.mode}
        if p.mode == 'none':
            return RefinementStatus(values=values)
        estimate = self.estimate
        values.update(rig_in_use=self.in_use, rig_frames=str(self.calibrator.added),
                      rig_resets=str(self.calibrator.resets),
                      rig_ms_per_frame=f'{self.cost_ms:.2f}')
        if estimate is None:
            values['rig_state'] = 'collecting'
            return RefinementStatus(values=values)
        values['rig_state'] = 'confident' if estimate.confident else \
            'planes only' if not estimate.in_plane_solved else \
            'provisional' if self._provisional(estimate) else 'collecting'
        values.update(
            rig_frames_matched=str(estimate.frames_matched), rig_matches=str(estimate.matches),
            rig_solve_ms=f'{estimate.solve_ms:.0f}')
        if estimate.in_plane_solved:
            values.update(rig_residual_mm=f'{1e3 * estimate.residual_m:.2f}',
                          rig_overlap=f'{estimate.overlap:.2f}',
                          rig_config_overlap=f'{estimate.prior_overlap:.2f}')
        _, differences = self._candidate(estimate)
        for name, difference in differences.items():
            values[f'rig_config_{name}_deg'] = f'{difference.angle_deg:.2f}'
            values[f'rig_config_{name}_mm'] = f'{1e3 * difference.offset_m:.1f}'
        off = {name: d for name, d in differences.items()
               if d.exceeds(p.warn_angle_deg, p.warn_offset_m)}
        if not off:
            return RefinementStatus(values=values)
        listed = ', '.join(f'{name} {d.angle_deg:.1f} deg / {1e3 * d.offset_m:.0f} mm'
                           for name, d in off.items())
        action = 'using the observed rig' if self.in_use == 'observed' else \
            "set rig_refinement.mode to 'use' or run tlessbot calibrate"
        if self.in_use == 'observed' and not estimate.confident:
            action = 'using the observed rig, provisional' if self._provisional(estimate) \
                else 'using the configured cameras levelled on the tables they see'
        return RefinementStatus(True, f'the configured rig differs from what the cameras see: '
                                      f'{listed} ({action})', values)


def refined_pipeline(refiner: RigRefiner, views: Mapping[str, ViewInput],
                     make_pipeline: Callable[[Rig], PerceptionPipeline]) -> PerceptionPipeline:
    """A frame's pipeline with the rig the refiner holds after observing this frame.

    ``make_pipeline(rig)`` builds the frame's pipeline and reads each view with its camera's
    pose in ``rig`` (``ViewInput.T_world_camera``). The planes the pipeline finds for its
    table frames (once per depth image) are handed to the refiner, so the frame's tables are
    searched once; a frame that changes the rig gets a pipeline with the new one (its planes
    found again, with the new rig's plane as the guide).
    """
    pipeline = make_pipeline(refiner.rig)
    planes = {name: pipeline.table_frame(name, view).observed for name, view in views.items()
              if view.depth_m is not None}
    if refiner.observe({name: view.depth_m for name, view in views.items()},
                       K={name: view.intrinsics.K for name, view in views.items()},
                       planes=planes):
        pipeline = make_pipeline(refiner.rig)
    return pipeline
