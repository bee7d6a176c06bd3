"""Training crops for ``tlessbot train --recipe clutter`` (the default): turntable renders of each
part pasted among other parts on random tables, re-photographed and cut with loose boxes
(:mod:`tlessbot_ros.sim.clutter`), described as box crops (``HogParams(crop_mode='box')``).

Measured on real RealSense frames in ``docs/bench/real-recognition.md``.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np

from tlessbot_ros.core.recognise import BACKGROUND_ID, HogParams, hog_features, normalise_crop
from tlessbot_ros.core.recognise.hog import box_size_features
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.sim.clutter import ClutterParams, Patch, clutter_crops


@dataclass(frozen=True)
class ClutterRecipe:
    """Views rendered for cluttered training.

    Attributes:
        copies: cluttered crops made of each rendered view.
        distance_m: (min, max) camera distance of the views, wide enough for a camera
            0.3 m above a bench and the cell's top camera at 1.1 m.
        elevation_deg: (min, max) camera elevation above the table.
        clutter: how each view is put among neighbours.
        shape_drop: share of crops whose shape part is blanked (NaN: filled with the training
            mean, as a frame without depth is at inference), so that the model also learns
            to name parts from the image alone; with clean rendered depth the shape features
            would otherwise decide every training crop alone.
        background_share: share of crops that leave the part out and are labelled
            ``BACKGROUND_ID``: the model learns a background class, and a box without a part
            of the set is reported as unknown (0). Off by default: on real piles it costs
            more top-1 than it saves (docs/bench/real-recognition.md).
    """

    copies: int = 10
    distance_m: tuple[float, float] = (0.3, 1.2)
    elevation_deg: tuple[float, float] = (40.0, 90.0)
    clutter: ClutterParams = ClutterParams()
    shape_drop: float = 0.5
    background_share: float = 0.0


def clutter_features(models_dir: Path, hog: HogParams, *, ids: list[int] | None,
                     steps_deg: float, positions: int, seed: int,
                     recipe: ClutterRecipe = ClutterRecipe(),
                     shape_of: Callable[[object], np.ndarray] | None = None,
                     shape_dim: int = 0, smoothed_share: float = 0.0
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Render, clutter and describe: ((N, D) float32, (N,) int64 ids).

    D is ``hog.feature_dim`` (the HOG, and the box size with ``hog.box_size``) plus
    ``shape_dim`` values from ``shape_of(sample)`` (the shape
    vector of the clean turntable view, NaN where its depth is unusable) when given. A share
    ``smoothed_share`` (0-1) of the views has the stereo-like 'smoothed' depth
    (``TurntableParams.smoothed_depth_share``) that the shape vectors are read from.
    """
    from tqdm import tqdm

    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.turntable import Turntable, TurntableParams

    if hog.crop_mode != 'box':
        raise ValueError("cluttered crops are described as boxes: use crop_mode='box'")
    models = load_models(models_dir, ids)
    if len(models) < 2:
        raise TlessbotError(f'need at least 2 models to train, found {len(models)}')
    table = Turntable(models, params=TurntableParams(
        positions=positions, step_deg=steps_deg, augmentations=0,
        distance_m=recipe.distance_m, elevation_deg=recipe.elevation_deg,
        smoothed_depth_share=smoothed_share), seed=seed)
    targets, shapes, focal = [], [], []
    for sample in tqdm(table.samples(), total=len(table), desc='render', unit='view'):
        distance = float(np.linalg.norm(sample.T_world_camera[:3, 3]))
        targets.append((sample.obj_id, Patch(sample.rgb, sample.mask, distance)))
        focal.append(float(sample.K[0, 0]))
        if shape_of is not None:
            shapes.append(shape_of(sample))
    pool = [patch for _, patch in targets]
    count = len(targets) * recipe.copies
    crops = np.empty((count, hog.crop_px, hog.crop_px), np.uint8)
    labels = np.empty(count, np.int64)
    rows = np.empty(count, np.int64)  # the view each crop comes from
    boxes = np.empty((count, 4), np.float64)
    crop_iter = clutter_crops(targets, pool, copies=recipe.copies, seed=seed,
                              params=recipe.clutter, background_share=recipe.background_share,
                              background_id=BACKGROUND_ID)
    for i, (obj_id, crop) in enumerate(tqdm(crop_iter, total=count, desc='clutter',
                                            unit='crop')):
        crops[i] = normalise_crop(crop.rgb, crop.box, params=hog)
        labels[i] = obj_id
        rows[i] = i // recipe.copies
        boxes[i] = crop.box
    features = hog_features(crops, params=hog)
    if hog.box_size:  # each view's own focal length (one for all: the turntable's camera)
        log_focal = np.log(np.asarray(focal))[rows, None].astype(np.float32)
        features = np.hstack([features, box_size_features(boxes, 1.0) - log_focal])
    if shape_of is not None:
        shape = np.asarray(shapes, np.float32).reshape(len(targets), shape_dim)[rows]
        shape[np.random.default_rng([seed, 1]).random(count) < recipe.shape_drop] = np.nan
        shape[labels == BACKGROUND_ID] = np.nan  # no part: no shape to read
        features = np.hstack([features, shape])
    return features.astype(np.float32), labels


def recipe_with(assignments: Iterable[str] | None) -> ClutterRecipe:
    """The default :class:`ClutterRecipe` with ``NAME=VALUE`` overrides of its fields or of
    its :class:`~tlessbot_ros.sim.clutter.ClutterParams` (``a,b`` for a pair);
    ``photometric=false`` turns the random camera response off (for ablations)."""
    from tlessbot_ros.core.recognise.augment import PhotometricParams
    from tlessbot_ros.tools.support.overrides import apply_overrides

    recipe, clutter = ClutterRecipe(), ClutterParams()
    own = {f.name for f in fields(ClutterRecipe)} - {'clutter'}
    mine, theirs = [], []
    for assignment in assignments or []:
        name, _, value = assignment.partition('=')
        if name == 'photometric':
            if value.lower() in ('false', '0', 'off'):
                clutter = replace(clutter, photometric=PhotometricParams(
                    exposure=(1.0, 1.0), white_balance=0.0, gamma=(1.0, 1.0),
                    contrast=(1.0, 1.0), blur_prob=0.0, noise_sigma=(0.0, 0.0), jpeg_prob=0.0,
                    grey_prob=0.0))
            continue
        (mine if name in own else theirs).append(assignment)
    try:
        recipe = apply_overrides(recipe, mine)
        clutter = apply_overrides(clutter, theirs)
    except ValueError as error:
        raise TlessbotError(str(error)) from None
    return replace(recipe, clutter=clutter)
