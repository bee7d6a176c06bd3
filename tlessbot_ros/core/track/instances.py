"""Instance names that hold from frame to frame: ``<part>_<k>`` for a part that stays put.

Each frame's parts are matched to the live instances of their class (part name) by position
(Hungarian assignment on the distance between origins, in the world frame) with a distance gate
and a rotation gate; a matched part keeps its instance's name, an unmatched one gets the next
free ``k`` of its class (a part that moved beyond the gates is a new instance: the arm must not
take it for the one it planned on). An instance that no frame matched for ``ttl_s`` is dropped.
Stamps that go back, or forward by more than ``time_jump_s``, reset every name (a bag replayed
in a loop, a clock reset).

A part with symmetries is reported in the symmetry-equivalent pose nearest its instance's last
one (``T @ S`` over the group's transforms ``S``, model frame), so that it does not flip between
equivalent rotations from frame to frame; the rotation gate uses that nearest equivalent too.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ['InstanceTracker', 'Observation', 'TrackParams', 'TrackedPart']


@dataclass(frozen=True)
class TrackParams:
    """Matching options of :class:`InstanceTracker`.

    Attributes:
        gate_m: a part within this distance of an instance of its class (origins, metres) may
            be that instance; farther: a new instance.
        gate_deg: and turned by at most this much (nearest symmetry-equivalent rotation).
        ttl_s: an instance unmatched for this long (source stamps, seconds) is dropped.
        time_jump_s: stamps going forward by more than this, or back by more than 1 ms, reset
            every name.
    """

    gate_m: float = 0.03
    gate_deg: float = 30.0
    ttl_s: float = 3.0
    time_jump_s: float = 30.0

    def __post_init__(self) -> None:
        for name in ('gate_m', 'gate_deg', 'ttl_s', 'time_jump_s'):
            value = getattr(self, name)
            if not value > 0:   # NaN too
                raise ValueError(f'{name} must be > 0, got {value}')


@dataclass
class Observation:
    """One part found in a frame: its class (part name), pose ``T_world_part`` (4x4, metres)
    and score."""

    part: str
    T_world_part: np.ndarray
    score: float = 1.0


@dataclass
class TrackedPart:
    """An observation with its instance name; ``T_world_part`` is the symmetry-equivalent pose
    nearest the instance's last one; ``index`` is the observation's index in the frame;
    ``new`` is true when the name was given in this frame."""

    instance: str
    part: str
    T_world_part: np.ndarray
    score: float
    index: int
    new: bool


@dataclass
class _Instance:
    name: str
    part: str
    T_world_part: np.ndarray
    last_seen_ns: int


@dataclass
class InstanceTracker:
    """Names the parts of successive frames (see the module docstring).

    ``symmetries`` maps a part name to its (K, 4, 4) symmetry transforms (identity included,
    e.g. :meth:`~tlessbot_ros.core.common.symmetry.Symmetries.transforms`); parts without an
    entry have none.
    """

    params: TrackParams = field(default_factory=TrackParams)
    symmetries: dict[str, np.ndarray] = field(default_factory=dict)
    resets: int = 0
    _instances: list[_Instance] = field(default_factory=list)
    _next_k: dict[str, int] = field(default_factory=dict)
    _last_ns: int | None = None

    @property
    def instances(self) -> dict[str, np.ndarray]:
        """Live instances: name -> last reported ``T_world_part``."""
        return {i.name: i.T_world_part.copy() for i in self._instances}

    def reset(self) -> None:
        """Forget every instance; names start again at ``<part>_1``."""
        self._instances.clear()
        self._next_k.clear()
        self._last_ns = None

    def update(self, stamp_ns: int, observations: list[Observation]) -> list[TrackedPart]:
        """Name one frame's parts; returns one :class:`TrackedPart` per observation, in order."""
        self._check_time(int(stamp_ns))
        ttl_ns = int(self.params.ttl_s * 1e9)
        self._instances = [i for i in self._instances if stamp_ns - i.last_seen_ns <= ttl_ns]
        named: list[TrackedPart | None] = [None] * len(observations)
        for part in sorted({o.part for o in observations}):
            indices = [k for k, o in enumerate(observations) if o.part == part]
            for k, tracked in zip(indices, self._match_class(part, stamp_ns, [
                    observations[k] for k in indices])):
                tracked.index = k
                named[k] = tracked
        return [t for t in named if t is not None]

    def _check_time(self, stamp_ns: int) -> None:
        last = self._last_ns
        if last is not None and (stamp_ns < last - 1_000_000
                                 or stamp_ns - last > self.params.time_jump_s * 1e9):
            self.reset()
            self.resets += 1
        self._last_ns = stamp_ns if self._last_ns is None else max(self._last_ns, stamp_ns)

    def _match_class(self, part: str, stamp_ns: int, observations: list[Observation]
                     ) -> list[TrackedPart]:
        live = [i for i in self._instances if i.part == part]
        sym = self.symmetries.get(part)
        poses = [np.asarray(o.T_world_part, dtype=np.float64) for o in observations]
        matched: dict[int, tuple[_Instance, np.ndarray]] = {}
        if live:
            cost = np.full((len(poses), len(live)), np.inf)
            nearest: dict[tuple[int, int], np.ndarray] = {}
            for a, T in enumerate(poses):
                for b, inst in enumerate(live):
                    T_near, angle = nearest_equivalent(T, inst.T_world_part, sym)
                    distance = float(np.linalg.norm(T_near[:3, 3] - inst.T_world_part[:3, 3]))
                    if distance <= self.params.gate_m and angle <= self.params.gate_deg:
                        cost[a, b] = distance
                        nearest[a, b] = T_near
            finite = np.where(np.isfinite(cost), cost, 1e6)
            for a, b in zip(*linear_sum_assignment(finite)):
                if np.isfinite(cost[a, b]):
                    matched[int(a)] = (live[b], nearest[a, b])
        out = []
        for a, (obs, T) in enumerate(zip(observations, poses)):
            if a in matched:
                inst, T_near = matched[a]
                inst.T_world_part, inst.last_seen_ns = T_near, stamp_ns
                out.append(TrackedPart(inst.name, part, T_near.copy(), obs.score, a, False))
                continue
            k = self._next_k.get(part, 1)
            self._next_k[part] = k + 1
            inst = _Instance(f'{part}_{k}', part, T.copy(), stamp_ns)
            self._instances.append(inst)
            out.append(TrackedPart(inst.name, part, T.copy(), obs.score, a, True))
        return out


def nearest_equivalent(T: np.ndarray, T_reference: np.ndarray,
                       symmetries: np.ndarray | None) -> tuple[np.ndarray, float]:
    """The pose among ``T @ S`` (S in ``symmetries``, (K, 4, 4); None: identity only) whose
    rotation is nearest ``T_reference``'s, and that rotation angle in degrees."""
    T = np.asarray(T, dtype=np.float64)
    candidates = T[None] if symmetries is None else np.einsum('ij,kjl->kil', T, symmetries)
    # trace(R_ref^T R) for every candidate at once
    traces = np.einsum('ij,kij->k', T_reference[:3, :3], candidates[:, :3, :3])
    best = int(np.argmax(traces))
    angle = float(np.degrees(np.arccos(np.clip((traces[best] - 1.0) / 2.0, -1.0, 1.0))))
    return candidates[best].copy(), angle
