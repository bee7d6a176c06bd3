"""Linear classifiers over HOG (+ metric shape) descriptors: inference.

After the paper (§3.2, §6.1) the descriptor of a crop is its HOG ("paper features"). A model may
also carry :class:`~tlessbot_ros.core.recognise.ShapeParams` ("ours"): then the vector
is the HOG followed by metric shape features read from the aligned depth of the region (heights
above the table, footprint, yaw-normalised height map), which give back the physical size that
the 60×60 crop throws away. Where a region has no usable depth the shape part is filled with
its training mean (``shape_fill``), so it adds a constant and the HOG decides alone.

Prediction does not use scikit-learn: the fitted one-vs-rest weights are kept as a (D, C) matrix
(with the feature standardisation folded in) and ``argmax(x @ W + b)`` takes a fraction of the
time of scikit-learn's ``predict`` per crop (docs/bench/code-figures.md). The margin between
the best and second-best class score is the confidence; a crop whose margin is below
``reject_margin`` is labelled ``UNKNOWN_ID``.

A model may also put an RBF feature map
(:mod:`~tlessbot_ros.core.recognise.feature_map`, Nyström) in
front of the linear learner: the learner is still one of the four of
:mod:`~tlessbot_ros.core.recognise.training`, on ``phi(x)``.

Where things are: training (the learners, :class:`~tlessbot_ros.core.recognise.ClassifierParams`,
:func:`~tlessbot_ros.core.recognise.train_classifier`) is in
:mod:`~tlessbot_ros.core.recognise.training`; the model file (an ``.npz`` read with
``allow_pickle=False``) in :mod:`~tlessbot_ros.core.recognise.model_file`. A new, non-linear kind
of model implements :class:`~tlessbot_ros.core.recognise.model.Classifier` next to this class
(see :mod:`~tlessbot_ros.core.recognise.model`).

References:
    [1] Sensors 2020, 20, 2203 (the seed paper), §3.2, §6.1, Fig. 10.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, cast

import numpy as np

from tlessbot_ros.core.recognise.feature_map import RbfFeatureMap
from tlessbot_ros.core.recognise.hog import HogParams, box_from_mask, describe_regions
from tlessbot_ros.core.recognise.model import BACKGROUND_ID, LOADERS, UNKNOWN_ID
from tlessbot_ros.core.recognise.model_file import (
    FILE_MAGIC,
    corrupt_model,
    read_linear_classifier,
    write_linear_classifier,
)
from tlessbot_ros.core.recognise.shape import (
    ShapeParams,
    region_points_world,
    shape_features_batch,
)


@dataclass(frozen=True)
class Prediction:
    """Labels of N crops.

    Attributes:
        class_ids: (N,) int64 predicted object ids, ``UNKNOWN_ID`` where rejected.
        scores: (N,) float32 decision value of the best class.
        margins: (N,) float32 best minus second-best decision value (>= 0).
    """

    class_ids: np.ndarray
    scores: np.ndarray
    margins: np.ndarray


@dataclass(frozen=True)
class LinearClassifier:
    """A trained linear model over HOG (+ shape) descriptors, or over an RBF map of them.

    Attributes:
        weights: (D, C) float32, D = :attr:`feature_dim` (or ``feature_map.output_dim`` with
            a feature map), C classes.
        intercepts: (C,) float32.
        class_ids: (C,) int64 object ids of the columns; ``BACKGROUND_ID`` (-1) for a
            background class, whose wins are reported as ``UNKNOWN_ID``.
        hog_params: the crop normalisation and HOG settings the model was trained with.
        kind: the learner (one of :data:`~tlessbot_ros.core.recognise.training.KINDS`).
        reject_margin: default reject threshold of :meth:`predict`.
        info: free-form JSON-serialisable training metadata (seed, sample counts, timings).
        shape_params: metric shape features appended to the HOG, or None (paper features).
        shape_fill: (shape_params.feature_dim,) float32 value of the shape part for regions
            without usable depth (the training mean); required with ``shape_params``.
        feature_map: RBF map applied to the descriptors before the weights, or None.
        margin_scale: median margin (best minus second-best score) of the model on its own
            training crops, the unit in which the pipeline judges how sure a margin is (0 =
            unknown, e.g. a model file from before it was stored).
    """

    weights: np.ndarray
    intercepts: np.ndarray
    class_ids: np.ndarray
    hog_params: HogParams = HogParams()
    kind: str = 'sgd'
    reject_margin: float = 0.0
    info: dict[str, Any] = field(default_factory=dict)
    shape_params: ShapeParams | None = None
    shape_fill: np.ndarray | None = None
    feature_map: RbfFeatureMap | None = None
    margin_scale: float = 0.0

    def __post_init__(self) -> None:
        w, b, ids = self.weights, self.intercepts, self.class_ids
        if w.ndim != 2 or b.shape != (w.shape[1],) or ids.shape != (w.shape[1],):
            raise ValueError(f'inconsistent shapes: weights {w.shape}, intercepts {b.shape}, '
                             f'class_ids {ids.shape}; need (D, C), (C,), (C,)')
        if self.feature_map is not None:
            if self.feature_map.input_dim != self.feature_dim:
                raise ValueError(f'the feature map takes {self.feature_map.input_dim} values but '
                                 f'the HOG (+ shape) settings give {self.feature_dim}')
            if w.shape[0] != self.feature_map.output_dim:
                raise ValueError(f'weights have {w.shape[0]} rows but the feature map gives '
                                 f'{self.feature_map.output_dim} values')
        elif w.shape[0] != self.feature_dim:
            raise ValueError(f'weights have {w.shape[0]} rows but the HOG (+ shape) settings '
                             f'give {self.feature_dim}-dimensional descriptors')
        if self.shape_params is not None and (
                self.shape_fill is None
                or np.shape(self.shape_fill) != (self.shape_params.feature_dim,)):
            raise ValueError('a model with shape_params needs a shape_fill of '
                             f'{self.shape_params.feature_dim} values')
        if w.shape[1] < 2:
            raise ValueError('a classifier needs at least 2 classes')

    @property
    def feature_dim(self) -> int:
        """Descriptor length: HOG, plus the shape vector when ``shape_params`` is set."""
        extra = 0 if self.shape_params is None else self.shape_params.feature_dim
        return self.hog_params.feature_dim + extra

    @property
    def uses_depth(self) -> bool:
        """True for the "ours" models (HOG + metric shape features)."""
        return self.shape_params is not None

    def describe(self, image: np.ndarray, masks: list[np.ndarray] | None = None,
                 boxes: Sequence[Sequence[float]] | None = None, *,
                 depth_m: np.ndarray | None = None,
                 K: np.ndarray | None = None,
                 T_world_camera: np.ndarray | None = None) -> np.ndarray:
        """Descriptors of the regions of one frame, as this model expects them.

        Args:
            image: (H, W, 3) RGB or (H, W) grey frame.
            masks: N (H, W) bool region masks (or None with ``boxes``).
            boxes: N (x, y, w, h) boxes in pixels (or None: the masks' boxes).
            depth_m: (H, W) aligned z-depth in metres (0/NaN invalid), or None.
            K: (3, 3) camera matrix of the image (needed with ``depth_m``; its focal length
                is the box size's unit with ``hog_params.box_size``).
            T_world_camera: (4, 4) camera pose in the table frame (needed with ``depth_m``).

        Returns:
            (N, feature_dim) float32. Without depth, extrinsics or enough valid points, a
            region's shape part is ``shape_fill``.
        """
        if boxes is None and masks is not None:  # one box per mask, shared by both steps
            boxes = [box_from_mask(mask) for mask in masks]
        hog = describe_regions(image, boxes, masks, params=self.hog_params,
                               focal_px=None if K is None else float(np.asarray(K)[0, 0]))
        if self.shape_params is None:
            return hog
        shape = np.tile(np.asarray(self.shape_fill, np.float32), (len(hog), 1))
        if depth_m is not None and K is not None and T_world_camera is not None:
            depth_m = np.asarray(depth_m)
            points = [region_points_world(
                depth_m, masks[i] if masks is not None else  # else boxes: describe_regions
                _box_mask(boxes[i], depth_m.shape),  # type: ignore[index]
                K, T_world_camera, box=None if boxes is None else boxes[i])
                for i in range(len(hog))]
            values = shape_features_batch(points, params=self.shape_params)
            known = ~np.isnan(values[:, 0])
            shape[known] = values[known]
        return np.hstack([hog, shape])

    def decision_function(self, features: np.ndarray) -> np.ndarray:
        """(N, D) float32 descriptors -> (N, C) float32 class scores."""
        features = np.asarray(features, dtype=np.float32)
        if features.ndim == 1:
            features = features[None]
        if features.shape[1] != self.feature_dim:
            raise ValueError(f'descriptors have {features.shape[1]} values, the model expects '
                             f'{self.feature_dim}: were they made with its hog_params '
                             '(and shape_params)?')
        if self.feature_map is not None:
            features = self.feature_map.transform(features)
        return cast(np.ndarray, features @ self.weights + self.intercepts)

    def predict(self, features: np.ndarray, *, reject_margin: float | None = None) -> Prediction:
        """Best class of each descriptor; ``UNKNOWN_ID`` where the margin is below the threshold.

        Args:
            features: (N, D) or (D,) float32 HOG descriptors.
            reject_margin: overrides the model's ``reject_margin``.
        """
        return self.predict_scores(self.decision_function(features), reject_margin=reject_margin)

    def predict_scores(self, scores: np.ndarray, *, reject_margin: float | None = None
                       ) -> Prediction:
        """:meth:`predict` on (N, C) class scores already computed (e.g. summed over the views
        that see a part)."""
        scores = np.asarray(scores, np.float32)
        if scores.ndim == 1:
            scores = scores[None]
        best_col = np.argmax(scores, axis=1)
        top2 = -np.partition(-scores, 1, axis=1)[:, :2]  # [:, 0] best, [:, 1] second best
        best = top2[:, 0]
        margins = (top2[:, 0] - top2[:, 1]).astype(np.float32)
        threshold = self.reject_margin if reject_margin is None else reject_margin
        ids = self.class_ids[best_col].astype(np.int64)
        ids[(margins < threshold) | (ids == BACKGROUND_ID)] = UNKNOWN_ID
        return Prediction(ids, best.astype(np.float32), margins)

    def ranked_classes(self, scores: np.ndarray, k: int) -> np.ndarray:
        """(N, C) class scores -> (N, min(k, parts)) int64 object ids, best first (the
        background class, if learnt, is never among them)."""
        scores = np.asarray(scores)
        if scores.ndim == 1:
            scores = scores[None]
        parts = self.class_ids != BACKGROUND_ID
        k = max(1, min(int(k), int(parts.sum())))
        order = np.argsort(-scores[:, parts], axis=1, kind='stable')[:, :k]
        return cast(np.ndarray, self.class_ids[parts][order].astype(np.int64))

    def save(self, path: str | Path) -> None:
        """Write the model as a compressed ``.npz`` (no pickled objects); the keys are listed
        in :func:`~tlessbot_ros.core.recognise.model_file.write_linear_classifier`."""
        write_linear_classifier(path, **{f.name: getattr(self, f.name) for f in fields(self)})

    @classmethod
    def load(cls, path: str | Path) -> LinearClassifier:
        """Read a model written by :meth:`save`; raises ``ModelFileError`` if it is not one."""
        kwargs = read_linear_classifier(path)
        try:
            return cls(**kwargs)
        except (ValueError, TypeError) as error:
            raise corrupt_model(Path(path), error) from None


def save_linear_classifier(model: LinearClassifier, path: str | Path) -> None:
    """Write ``model`` as a compressed ``.npz`` (:meth:`LinearClassifier.save`)."""
    model.save(path)


def load_linear_classifier(path: str | Path) -> LinearClassifier:
    """Read a model written by :func:`save_linear_classifier` (:meth:`LinearClassifier.load`);
    raises ``ModelFileError`` if it is not one (missing, unreadable, another magic, a newer
    format or corrupt)."""
    return LinearClassifier.load(path)


LOADERS[FILE_MAGIC] = load_linear_classifier


def _box_mask(box: Sequence[float], shape: tuple[int, ...]) -> np.ndarray:
    x, y, w, h = (int(round(float(v))) for v in box)
    mask = np.zeros(shape, bool)
    mask[max(y, 0):max(y + h, 0), max(x, 0):max(x + w, 0)] = True
    return mask
