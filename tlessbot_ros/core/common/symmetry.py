"""Symmetries of rigid objects: representation and BOP ``models_info.json`` parsing.

A symmetry of a model is a rigid transform ``S`` (model frame) that maps the surface onto
itself, so the poses ``T`` and ``T @ S`` look the same. BOP represents a model's symmetries as a
list of discrete transforms and a list of continuous rotation axes (axis direction and a point
on the axis); see Hodaň et al., "BOP Challenge 2020 on 6D Object Localization", ECCV-W 2020,
and bop_toolkit ``misc.get_symmetry_transformations``. Detection from a mesh:
:func:`~tlessbot_ros.core.common.symmetry_detect.detect_symmetries`.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from tlessbot_ros.core.common.geometry import make_transform, rotation_about_axis


def _as_transform(T: np.ndarray) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ValueError(f'a symmetry transform must be 4x4, got shape {T.shape}')
    return T


@dataclass(frozen=True, eq=False)
class Symmetries:
    """The symmetry group of a model, as BOP describes it.

    Attributes:
        discrete: (4, 4) float64 transforms in the model frame (translation in metres); the
            identity is always included (added when missing).
        continuous: ``(axis (3,) unit vector, offset (3,) metres)`` per continuous rotation axis:
            rotations by any angle about the line through ``offset`` along ``axis``.
    """

    discrete: tuple[np.ndarray, ...] = field(default_factory=lambda: (np.eye(4),))
    continuous: tuple[tuple[np.ndarray, np.ndarray], ...] = ()

    def __post_init__(self) -> None:
        discrete = [_as_transform(T) for T in self.discrete]
        if not any(np.allclose(T, np.eye(4), atol=1e-6) for T in discrete):
            discrete.insert(0, np.eye(4))
        else:  # identity first, exactly
            discrete = [np.eye(4)] + [T for T in discrete if not np.allclose(T, np.eye(4),
                                                                            atol=1e-6)]
        continuous = []
        for item in self.continuous:
            if len(item) != 2:
                raise ValueError('each continuous symmetry must be (axis, offset)')
            axis = np.asarray(item[0], dtype=np.float64).reshape(3)
            norm = np.linalg.norm(axis)
            if norm < 1e-12:
                raise ValueError('a continuous symmetry axis must be non-zero')
            offset = np.asarray(item[1], dtype=np.float64).reshape(3)
            continuous.append((axis / norm, offset))
        object.__setattr__(self, 'discrete', tuple(discrete))
        object.__setattr__(self, 'continuous', tuple(continuous))

    @property
    def is_trivial(self) -> bool:
        """True when the only symmetry is the identity."""
        return len(self.discrete) == 1 and not self.continuous

    def transforms(self, *, step_rad: float = np.radians(1.0)) -> np.ndarray:
        """All symmetry transforms, continuous axes discretised; (K, 4, 4) float64.

        As bop_toolkit ``get_symmetry_transformations``: each continuous rotation is sampled at
        ``ceil(2 pi / step_rad)`` equal steps and composed with every discrete transform
        (``S = S_continuous @ S_discrete``). The identity is element 0.
        """
        if step_rad <= 0:
            raise ValueError(f'step_rad must be positive, got {step_rad}')
        continuous = [np.eye(4)]
        for axis, offset in self.continuous:
            count = int(np.ceil(2 * np.pi / step_rad))
            sampled = []
            for k in range(count):
                R = rotation_about_axis(axis, 2 * np.pi * k / count)
                sampled.append(make_transform(R, offset - R @ offset))
            continuous = [A @ B for A in sampled for B in continuous]
        return np.stack([C @ D for C in continuous for D in self.discrete])

    def describe(self) -> str:
        """Short text: 'none', 'continuous', '2-fold', 'continuous + 2-fold', ..."""
        parts = []
        if self.continuous:
            parts.append('continuous' if len(self.continuous) == 1
                         else f'{len(self.continuous)} continuous axes')
        if len(self.discrete) > 1:
            parts.append(f'{len(self.discrete)}-fold')
        return ' + '.join(parts) if parts else 'none'


def symmetries_from_models_info(entry: Mapping[str, Any]) -> Symmetries:
    """Symmetries from one object's entry of BOP ``models_info.json``.

    Args:
        entry: dict with optional ``symmetries_discrete`` (list of 16 numbers: a row-major 4x4
            transform, translation in mm) and ``symmetries_continuous`` (list of
            ``{'axis': [3], 'offset': [3] mm}``).

    Returns:
        :class:`Symmetries` in metres (identity added to the discrete set).
    """
    discrete = []
    for values in entry.get('symmetries_discrete', []) or []:
        T = np.asarray(values, dtype=np.float64)
        if T.size != 16:
            raise ValueError(f'symmetries_discrete entries must have 16 numbers, got {T.size}')
        T = T.reshape(4, 4).copy()
        T[:3, 3] /= 1000.0
        discrete.append(T)
    continuous = []
    for item in entry.get('symmetries_continuous', []) or []:
        if 'axis' not in item:
            raise ValueError('symmetries_continuous entries need an "axis"')
        offset = np.asarray(item.get('offset', [0.0, 0.0, 0.0]), dtype=np.float64) / 1000.0
        continuous.append((np.asarray(item['axis'], dtype=np.float64), offset))
    return Symmetries(discrete=tuple(discrete), continuous=tuple(continuous))


def symmetries_to_models_info(symmetries: Symmetries) -> dict[str, Any]:
    """Inverse of :func:`symmetries_from_models_info` (mm, flattened; identity omitted)."""
    entry: dict[str, Any] = {}
    discrete = []
    for T in symmetries.discrete[1:]:
        T_mm = T.copy()
        T_mm[:3, 3] *= 1000.0
        discrete.append([float(v) for v in T_mm.ravel()])
    if discrete:
        entry['symmetries_discrete'] = discrete
    if symmetries.continuous:
        entry['symmetries_continuous'] = [
            {'axis': [float(v) for v in axis], 'offset': [float(v) * 1000.0 for v in offset]}
            for axis, offset in symmetries.continuous]
    return entry

