"""Cluttered training crops: rendered parts pasted among rendered neighbours on random tables.

Turntable renders (:mod:`tlessbot_ros.sim.turntable`) show one part on a plain plate; a real
cell's localiser cuts a part with a loose box out of a table that holds other parts. This module
pastes each turntable view of a part onto a random table texture among other parts' views (at
the same scale: as a neighbour on the same table would be), lets neighbours cover it partly,
draws a random camera response (:func:`~tlessbot_ros.core.recognise.augment.photometric`) and
cuts a loose box around it (:func:`~tlessbot_ros.core.recognise.augment.loose_box`).

A neighbour drawn from a pool of windows is scaled by the ratio of the two camera distances,
so that parts keep their relative sizes. Every sample is deterministic given the seed.
"""
from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import cv2
import numpy as np

from tlessbot_ros.core.recognise.augment import (
    PhotometricParams,
    loose_box,
    photometric,
    texture_background,
)


@dataclass(frozen=True)
class ClutterParams:
    """How a part's view is put among clutter.

    Attributes:
        context: (min, max) side of the canvas relative to the part's longer side.
        neighbours: (min, max) other parts pasted around (and partly over) the part.
        over_prob: chance that a neighbour is pasted over the part rather than under it.
        max_cover: a neighbour over the part may hide at most this share of its silhouette.
        grow: (min, max) relative growth of each side of the cut box (see ``loose_box``).
        shift: largest shift of the box centre relative to its side.
        shadow_prob: chance of a soft dark shadow under each pasted part.
        photometric: the random camera response.
    """

    context: tuple[float, float] = (1.5, 3.0)
    neighbours: tuple[int, int] = (0, 6)
    over_prob: float = 0.3
    max_cover: float = 0.35
    grow: tuple[float, float] = (0.0, 0.3)
    shift: float = 0.1
    shadow_prob: float = 0.5
    photometric: PhotometricParams = field(default_factory=PhotometricParams)

    def __post_init__(self) -> None:
        if not 1.0 <= self.context[0] <= self.context[1]:
            raise ValueError(f'context must be (min, max) with 1 <= min <= max, got '
                             f'{self.context}')
        if not 0 <= self.neighbours[0] <= self.neighbours[1]:
            raise ValueError(f'neighbours must be (min, max) with 0 <= min <= max, got '
                             f'{self.neighbours}')
        if not 0.0 <= self.max_cover < 1.0:
            raise ValueError(f'max_cover must be in [0, 1), got {self.max_cover}')


@dataclass(frozen=True)
class Patch:
    """A rendered part: (h, w, 3) uint8 ``rgb``, (h, w) bool ``mask``, camera distance (m)."""

    rgb: np.ndarray
    mask: np.ndarray
    distance_m: float


@dataclass(frozen=True)
class ClutterCrop:
    """A training image: (H, W, 3) uint8 ``rgb``, the cut ``box`` (x, y, w, h) and the
    part's (H, W) bool ``mask`` in it (the part's visible pixels, neighbours removed)."""

    rgb: np.ndarray
    box: tuple[int, int, int, int]
    mask: np.ndarray


def _paste(canvas: np.ndarray, owner: np.ndarray, patch: Patch, scale: float, x0: int, y0: int,
           label: int, shadow: bool, rng: np.random.Generator) -> None:
    """Paste ``patch`` scaled by ``scale`` with its top-left at (x0, y0); ``owner`` marks
    which pasted part each canvas pixel shows."""
    h, w = patch.mask.shape
    size = (max(int(round(w * scale)), 1), max(int(round(h * scale)), 1))
    rgb = cv2.resize(patch.rgb, size, interpolation=cv2.INTER_AREA if scale < 1
                     else cv2.INTER_LINEAR).astype(np.float32) / 255.0
    alpha = cv2.resize(patch.mask.astype(np.float32), size, interpolation=cv2.INTER_LINEAR)
    H, W = owner.shape
    xa, ya, xb, yb = max(x0, 0), max(y0, 0), min(x0 + size[0], W), min(y0 + size[1], H)
    if xb <= xa or yb <= ya:
        return
    sub = (slice(ya - y0, yb - y0), slice(xa - x0, xb - x0))
    region = (slice(ya, yb), slice(xa, xb))
    a = alpha[sub]
    if shadow:
        blur = max(1.0, 0.05 * max(size))
        soft = cv2.GaussianBlur(a, (0, 0), blur)
        dx, dy = rng.normal(0.0, 0.03 * max(size), 2).astype(int)
        soft = np.roll(soft, (dy, dx), axis=(0, 1))
        canvas[region] *= (1.0 - rng.uniform(0.2, 0.6) * soft)[..., None]
    canvas[region] = canvas[region] * (1.0 - a[..., None]) + rgb[sub] * a[..., None]
    owner[region][a > 0.5] = label


def clutter_crop(target: Patch, pool: list[Patch], rng: np.random.Generator, *,
                 params: ClutterParams = ClutterParams(),
                 with_target: bool = True) -> ClutterCrop:
    """One cluttered, re-photographed crop of ``target`` (neighbours drawn from ``pool``).

    Args:
        target: the part to be recognised.
        pool: rendered views of any parts, used as neighbours (may be empty).
        rng: the random generator.
        params: the clutter settings.
        with_target: False leaves the part out: the box then holds only table and
            neighbours (a background crop; its ``mask`` is empty).
    """
    if not target.mask.any():
        raise ValueError('target patch has an empty mask')
    p = params
    h, w = target.mask.shape
    side = int(round(max(h, w) * rng.uniform(*p.context))) + 2
    canvas = texture_background((side, side), rng)
    owner = np.zeros((side, side), np.int32)
    tx, ty = (side - w) // 2, (side - h) // 2
    count = int(rng.integers(p.neighbours[0], p.neighbours[1] + 1)) if pool else 0
    over = []
    for k in range(count):
        other = pool[int(rng.integers(len(pool)))]
        scale = other.distance_m / max(target.distance_m, 1e-6)
        oh, ow = (int(round(s * scale)) for s in other.mask.shape)
        x0 = int(rng.integers(-ow // 2, side - ow // 2 + 1))
        y0 = int(rng.integers(-oh // 2, side - oh // 2 + 1))
        if rng.random() < p.over_prob:
            over.append((other, scale, x0, y0))
        else:
            _paste(canvas, owner, other, scale, x0, y0, k + 2, rng.random() < p.shadow_prob,
                   rng)
    if with_target:
        _paste(canvas, owner, target, 1.0, tx, ty, 1, rng.random() < p.shadow_prob, rng)
    visible_before = int((owner == 1).sum())
    for k, (other, scale, x0, y0) in enumerate(over):
        trial_canvas, trial_owner = canvas.copy(), owner.copy()
        _paste(trial_canvas, trial_owner, other, scale, x0, y0, count + k + 2, False, rng)
        if (trial_owner == 1).sum() >= (1.0 - p.max_cover) * visible_before:
            canvas, owner = trial_canvas, trial_owner
    rgb = photometric((np.clip(canvas, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8), rng,
                      params=p.photometric)
    mask = owner == 1
    rows, cols = np.nonzero(mask if with_target else target.mask)
    offset = (0, 0) if with_target else (tx, ty)
    tight = (int(cols.min()) + offset[0], int(rows.min()) + offset[1], int(np.ptp(cols)) + 1,
             int(np.ptp(rows)) + 1)
    return ClutterCrop(rgb, loose_box(tight, rng, grow=p.grow, shift=p.shift), mask)


def clutter_crops(targets: list[tuple[int, Patch]], pool: list[Patch], *, copies: int,
                  seed: int, params: ClutterParams = ClutterParams(),
                  background_share: float = 0.0, background_id: int = -1
                  ) -> Iterator[tuple[int, ClutterCrop]]:
    """``copies`` cluttered crops of each (obj_id, patch) target, in order: (obj_id, crop).

    With ``background_share`` > 0, each copy is instead, with that chance, a background crop
    (the part left out, same box), labelled ``background_id``."""
    for index, (obj_id, target) in enumerate(targets):
        rng = np.random.default_rng([seed, index])
        for _ in range(copies):
            part = rng.random() >= background_share
            yield (obj_id if part else background_id,
                   clutter_crop(target, pool, rng, params=params, with_target=part))
