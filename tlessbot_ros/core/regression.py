"""Checking a run's poses against approved ones, frame by frame (``tlessbot check``).

An approved run holds, per frame (source stamp), the parts the graph published: name, pose in a
frame, score. A new run of the same bag is matched to it part by part: within a frame, poses
of the same name are paired nearest first, the distance measured with the model's symmetries
(:func:`~tlessbot_ros.core.metrics.pose_error`: a symmetric part turned onto an equivalent pose
has not moved). What stays unpaired is a part missing or a part added, unless a missing and an
added part lie at the same place: then the part's name changed.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from tlessbot_ros.core.common import Symmetries
from tlessbot_ros.core.metrics import PoseError, pose_error

MATCH = 'match'
MOVED = 'moved'               # paired, but beyond the position or angle tolerance
FRAME_CHANGED = 'frame changed'   # paired by name, published in another frame
RENAMED = 'renamed'           # at an approved part's place, under another name
MISSING = 'missing'           # approved, not published now
ADDED = 'added'               # published now, not approved
STATUSES = (MATCH, MOVED, FRAME_CHANGED, RENAMED, MISSING, ADDED)


@dataclass(frozen=True)
class PartPose:
    """One part the graph published for a frame.

    Attributes:
        name: the part's name (its CAD file's stem, e.g. ``obj_05``).
        T: (4, 4) pose of the part in ``frame_id``, metres.
        frame_id: the frame of the pose (a camera's optical frame or the world frame).
        score: the pose estimator's fitness in [0, 1] (None when not known); reported only.
    """

    name: str
    T: np.ndarray
    frame_id: str
    score: float | None = None


@dataclass(frozen=True)
class Tolerance:
    """How far a part may move before the check fails.

    Attributes:
        position_m: largest translation change, metres (5 mm: what a pick tolerates).
        angle_deg: largest rotation change, degrees, the nearest symmetric pose taken.
        rename_radius_m: a missing and an added part closer than this are one part whose
            name changed, metres.
    """

    position_m: float = 0.005
    angle_deg: float = 2.0
    rename_radius_m: float = 0.02

    def __post_init__(self) -> None:
        if not (self.position_m > 0 and self.angle_deg > 0 and self.rename_radius_m >= 0):
            raise ValueError('tolerances must be positive (position_m, angle_deg) and '
                             f'rename_radius_m >= 0, got {self}')

    def allows(self, error: PoseError) -> bool:
        return error.translation_m <= self.position_m and error.rotation_deg <= self.angle_deg


@dataclass(frozen=True)
class PartCheck:
    """The outcome for one part of one frame."""

    stamp_ns: int
    status: str
    expected: PartPose | None
    actual: PartPose | None
    error: PoseError | None = None

    @property
    def ok(self) -> bool:
        return self.status == MATCH

    @property
    def name(self) -> str:
        part = self.expected or self.actual
        assert part is not None
        return part.name

    def describe(self) -> str:
        """One line: what happened to the part, with the figures."""
        if self.status in (MATCH, MOVED):
            assert self.error is not None
            return (f'{"within tolerance" if self.ok else "moved"}: '
                    f'{1e3 * self.error.translation_m:.2f} mm, '
                    f'{self.error.rotation_deg:.2f} deg')
        if self.status == FRAME_CHANGED:
            assert self.expected is not None and self.actual is not None
            return f'frame changed: {self.expected.frame_id} -> {self.actual.frame_id}'
        if self.status == RENAMED:
            assert self.expected is not None and self.actual is not None
            return f'name changed: {self.expected.name} -> {self.actual.name}'
        if self.status == MISSING:
            return 'missing: approved, not published now'
        return 'added: published now, not approved'


def _pair_cost(error: PoseError, tolerance: Tolerance) -> float:
    return error.translation_m / tolerance.position_m + error.rotation_deg / tolerance.angle_deg


def match_frame(stamp_ns: int, expected: Sequence[PartPose], actual: Sequence[PartPose],
                symmetries: Mapping[str, Symmetries], tolerance: Tolerance = Tolerance()
                ) -> list[PartCheck]:
    """Pair one frame's published parts with its approved ones.

    Parts of the same name are paired nearest first (position and angle, each in units of its
    tolerance; the angle to the nearest pose the part's ``symmetries`` make equivalent); a
    pair in two different frames is paired last and reported as :data:`FRAME_CHANGED`.
    Unpaired approved and published parts within ``tolerance.rename_radius_m`` of each other
    (same frame) are :data:`RENAMED`; the rest are :data:`MISSING` and :data:`ADDED`.

    Returns:
        One :class:`PartCheck` per approved part and per unpaired published part, in the order
        of ``expected``, then the added ones.
    """
    candidates: list[tuple[int, float, int, int, PoseError | None]] = []
    for i, exp in enumerate(expected):
        for j, act in enumerate(actual):
            if exp.name != act.name:
                continue
            if exp.frame_id != act.frame_id:
                candidates.append((1, 0.0, i, j, None))
                continue
            pair_error = pose_error(act.T, exp.T, symmetries.get(exp.name))
            candidates.append((0, _pair_cost(pair_error, tolerance), i, j, pair_error))
    candidates.sort(key=lambda c: c[:2])
    by_expected: dict[int, PartCheck] = {}
    used: set[int] = set()
    for changed, _, i, j, error in candidates:
        if i in by_expected or j in used:
            continue
        used.add(j)
        status = FRAME_CHANGED if changed or error is None else \
            MATCH if tolerance.allows(error) else MOVED
        by_expected[i] = PartCheck(stamp_ns, status, expected[i], actual[j], error)
    renames = sorted(
        (float(np.linalg.norm(exp.T[:3, 3] - act.T[:3, 3])), i, j)
        for i, exp in enumerate(expected) if i not in by_expected
        for j, act in enumerate(actual) if j not in used and act.frame_id == exp.frame_id)
    for distance, i, j in renames:
        if distance <= tolerance.rename_radius_m and i not in by_expected and j not in used:
            used.add(j)
            by_expected[i] = PartCheck(stamp_ns, RENAMED, expected[i], actual[j])
    checks = [by_expected.get(i) or PartCheck(stamp_ns, MISSING, exp, None)
              for i, exp in enumerate(expected)]
    return checks + [PartCheck(stamp_ns, ADDED, None, act)
                     for j, act in enumerate(actual) if j not in used]


def check_frames(expected: Mapping[int, Sequence[PartPose]],
                 actual: Mapping[int, Sequence[PartPose]],
                 symmetries: Mapping[str, Symmetries], tolerance: Tolerance = Tolerance()
                 ) -> list[PartCheck]:
    """:func:`match_frame` for every frame (source stamp, ns) of either run, in stamp order; a
    frame only one run has counts its parts as missing or added."""
    checks: list[PartCheck] = []
    for stamp in sorted(set(expected) | set(actual)):
        checks += match_frame(stamp, expected.get(stamp, ()), actual.get(stamp, ()),
                              symmetries, tolerance)
    return checks
