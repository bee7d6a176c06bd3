"""Linear classifiers over HOG (+ metric shape) descriptors: SGD, Perceptron, PA-I and PA-II.

After the paper (§3.2, §6.1) the descriptor of a crop is its HOG ("paper features"). A model may
also carry :class:`~tlessbot_ros.core.recognise.ShapeParams` ("ours"): then the vector
is the HOG followed by metric shape features read from the aligned depth of the region (heights
above the table, footprint, yaw-normalised height map), which give back the physical size that
the 60×60 crop throws away. Where a region has no usable depth the shape part is filled with
its training mean (``shape_fill``), so it adds a constant and the HOG decides alone.

Training uses scikit-learn's online learners through ``partial_fit`` on shuffled mini-batches
(through one ``fit`` over all samples for feature-map models, see :meth:`OnlineTrainer.fit`):

- ``'sgd'``: ``SGDClassifier`` (linear SVM, hinge loss, L2 penalty ``alpha``, optimal rate);
- ``'perceptron'``: ``Perceptron`` (Rosenblatt's rule);
- ``'pa1'`` / ``'pa2'``: Passive-Aggressive I / II of Crammer et al. [1], as
  ``SGDClassifier(loss='hinge', penalty=None, learning_rate='pa1' | 'pa2', eta0=C)``, the
  replacement of ``PassiveAggressiveClassifier`` (deprecated in scikit-learn 1.8, removed in 1.10).

Prediction does not use scikit-learn: the fitted one-vs-rest weights are kept as a (D, C) matrix
(with the feature standardisation folded in) and ``argmax(x @ W + b)`` takes about 0.01 ms per
crop instead of 0.3 ms for ``predict``. The margin between the best and second-best class score
is the confidence; a crop whose margin is below ``reject_margin`` is labelled ``UNKNOWN_ID``.

A model may also put an RBF feature map
(:mod:`~tlessbot_ros.core.recognise.feature_map`, Nyström) in
front of the linear learner: the learner is still one of the four above, on ``phi(x)``.

The model file is an ``.npz`` read with ``allow_pickle=False``; see :meth:`LinearClassifier.save`.

References:
    [1] K. Crammer et al., "Online Passive-Aggressive Algorithms", JMLR 7, 2006.
    [2] Sensors 2020, 20, 2203 (the seed paper), §3.2, §6.1, Fig. 10.
"""
from __future__ import annotations

import json
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core.recognise.feature_map import RbfFeatureMap, fit_rbf_map
from tlessbot_ros.core.recognise.hog import HogParams, describe_regions
from tlessbot_ros.core.recognise.model import LOADERS, UNKNOWN_ID
from tlessbot_ros.core.recognise.shape import (
    ShapeParams,
    region_points_world,
    shape_features_batch,
)
from tlessbot_ros.errors import ModelFileError

FORMAT_VERSION = 3  # 2 adds shape_params / shape_fill, 3 the feature map; 1 and 2 still load
FILE_MAGIC = 'tlessbot_ros.linear_classifier'
KINDS = ('sgd', 'perceptron', 'pa1', 'pa2')


@dataclass(frozen=True)
class ClassifierParams:
    """Training settings.

    Attributes:
        kind: one of ``KINDS``.
        epochs: passes over the training set (each shuffled); 10 by default: with 5, SGD
            had not settled (84.9 against 81.0 % for 5-epoch PA-II on 568 simulated crops).
        batch_size: samples per ``partial_fit`` call (the mini-batch).
        alpha: L2 regularisation of ``'sgd'`` (scikit-learn's ``alpha``).
        pa_c: aggressiveness C of PA-I / PA-II (scikit-learn's ``eta0``).
        standardise: scale each feature to zero mean and unit variance before training; the
            scaling is folded into the stored weights.
        reject_margin: default minimum margin (best minus second-best score) to accept a label;
            0 accepts everything.
        hog_weight: with shape features, the standardised HOG block is multiplied by this
            fixed factor before learning (a fixed feature map, folded into the stored
            weights): the rendered-vs-scene domain gap is larger for HOG than for the metric
            features, and a low weight keeps it from drowning them (measured in the README).
        average: keep the average of the weights over all updates (averaged SGD; for
            'perceptron' the averaged perceptron) instead of the last ones: less noisy
            weights, which carry better from the rendered training crops to the scenes.
        kernel_components: 0 learns on the descriptors themselves; M > 0 learns on an RBF
            feature map with M landmarks (:func:`~tlessbot_ros.core.recognise.fit_rbf_map`).
        kernel_axes: principal axes of the standardised descriptor the map keeps.
        kernel_gamma: RBF width of the map, relative to the descriptor length.
    """

    kind: str = 'sgd'
    epochs: int = 10
    batch_size: int = 256
    alpha: float = 1e-4
    pa_c: float = 0.1
    standardise: bool = True
    reject_margin: float = 0.0
    hog_weight: float = 0.1
    average: bool = False
    kernel_components: int = 0
    kernel_axes: int = 128
    kernel_gamma: float = 3.0

    def __post_init__(self) -> None:
        if self.kernel_components < 0 or self.kernel_axes < 1 or not self.kernel_gamma > 0:
            raise ValueError('need kernel_components >= 0, kernel_axes >= 1, kernel_gamma > 0')
        if self.hog_weight <= 0:
            raise ValueError(f'hog_weight must be > 0, got {self.hog_weight}')
        if self.kind not in KINDS:
            raise ValueError(f'kind must be one of {KINDS}, got {self.kind!r}')
        if self.epochs < 1 or self.batch_size < 1:
            raise ValueError('epochs and batch_size must be >= 1')
        if self.alpha <= 0 or self.pa_c <= 0:
            raise ValueError('alpha and pa_c must be > 0')
        if self.reject_margin < 0:
            raise ValueError(f'reject_margin must be >= 0, got {self.reject_margin}')


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
        class_ids: (C,) int64 object ids of the columns.
        hog_params: the crop normalisation and HOG settings the model was trained with.
        kind: the learner (one of ``KINDS``).
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
    info: dict = field(default_factory=dict)
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
                 boxes: list | None = None, *, depth_m: np.ndarray | None = None,
                 K: np.ndarray | None = None,
                 T_world_camera: np.ndarray | None = None) -> np.ndarray:
        """Descriptors of the regions of one frame, as this model expects them.

        Args:
            image: (H, W, 3) RGB or (H, W) grey frame.
            masks: N (H, W) bool region masks (or None with ``boxes``).
            boxes: N (x, y, w, h) boxes in pixels (or None: the masks' boxes).
            depth_m: (H, W) aligned z-depth in metres (0/NaN invalid), or None.
            K: (3, 3) camera matrix of the image (needed with ``depth_m``).
            T_world_camera: (4, 4) camera pose in the table frame (needed with ``depth_m``).

        Returns:
            (N, feature_dim) float32. Without depth, extrinsics or enough valid points, a
            region's shape part is ``shape_fill``.
        """
        if boxes is None and masks is not None:  # one box per mask, shared by both steps
            boxes = [_mask_box(mask) for mask in masks]
        hog = describe_regions(image, boxes, masks, params=self.hog_params)
        if self.shape_params is None:
            return hog
        shape = np.tile(np.asarray(self.shape_fill, np.float32), (len(hog), 1))
        if depth_m is not None and K is not None and T_world_camera is not None:
            depth_m = np.asarray(depth_m)
            points = [region_points_world(
                depth_m, masks[i] if masks is not None else _box_mask(boxes[i], depth_m.shape),
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
        return features @ self.weights + self.intercepts

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
        ids[margins < threshold] = UNKNOWN_ID
        return Prediction(ids, best.astype(np.float32), margins)

    def ranked_classes(self, scores: np.ndarray, k: int) -> np.ndarray:
        """(N, C) class scores -> (N, min(k, C)) int64 object ids, best first."""
        scores = np.asarray(scores)
        if scores.ndim == 1:
            scores = scores[None]
        k = max(1, min(int(k), scores.shape[1]))
        return self.class_ids[np.argsort(-scores, axis=1, kind='stable')[:, :k]].astype(np.int64)

    def save(self, path: str | Path) -> None:
        """Write the model as a compressed ``.npz`` (no pickled objects).

        Keys: ``magic``, ``format_version``, ``kind``, ``weights`` (D, C) float32,
        ``intercepts`` (C,) float32, ``class_ids`` (C,) int64, ``hog_params`` (JSON),
        ``reject_margin``, ``info`` (JSON), ``shape_params`` (JSON, "null" for paper features),
        ``shape_fill`` (F,) float32 (empty for paper features), ``map_mean`` (D,) float32,
        ``map_projection`` (D, k) and ``map_landmarks`` (M, k) float16, ``map_gamma`` (all
        empty / 0 without a feature map), ``margin_scale`` (absent from older files: 0).
        """
        fmap = self.feature_map
        empty = np.zeros(0, np.float32)
        shape_json = json.dumps(None if self.shape_params is None else
                                self.shape_params.to_dict())
        fill = empty if self.shape_fill is None else self.shape_fill
        np.savez_compressed(
            Path(path), magic=np.array(FILE_MAGIC), format_version=np.array(FORMAT_VERSION),
            kind=np.array(self.kind), weights=self.weights.astype(np.float32),
            intercepts=self.intercepts.astype(np.float32),
            class_ids=self.class_ids.astype(np.int64),
            hog_params=np.array(json.dumps(self.hog_params.to_dict())),
            reject_margin=np.array(float(self.reject_margin)),
            info=np.array(json.dumps(self.info)), shape_params=np.array(shape_json),
            shape_fill=np.asarray(fill, np.float32),
            map_mean=empty if fmap is None else fmap.mean,
            map_projection=empty if fmap is None else fmap.projection.astype(np.float16),
            map_landmarks=empty if fmap is None else fmap.landmarks.astype(np.float16),
            map_gamma=np.array(0.0 if fmap is None else fmap.gamma),
            margin_scale=np.array(float(self.margin_scale)))

    @classmethod
    def load(cls, path: str | Path) -> LinearClassifier:
        """Read a model written by :meth:`save`; raises ``ModelFileError`` if it is not one."""
        path = Path(path)
        if not path.is_file():
            raise ModelFileError(f'classifier model {path} does not exist')
        try:
            with np.load(path, allow_pickle=False) as data:
                arrays = {key: data[key] for key in data.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
            raise ModelFileError(f'{path} is not a readable classifier .npz ({error})') from None
        if str(arrays.get('magic', '')) != FILE_MAGIC:
            raise ModelFileError(f'{path} is not a tlessbot classifier model (wrong magic); '
                                 "make one with 'tlessbot train'")
        version = int(arrays.get('format_version', -1))
        if version not in (1, 2, FORMAT_VERSION):
            raise ModelFileError(f'{path} has model format version {version}; this tlessbot '
                                 f'reads version {FORMAT_VERSION}: retrain it')
        try:
            hog_dict = json.loads(str(arrays['hog_params']))
            known = {f.name for f in fields(HogParams)}
            hog_params = HogParams(**{k: v for k, v in hog_dict.items() if k in known})
            shape_dict = json.loads(str(arrays.get('shape_params', 'null')))
            shape_params = None if shape_dict is None else ShapeParams.from_dict(shape_dict)
            feature_map = None
            if float(arrays.get('map_gamma', 0.0)) > 0:
                feature_map = RbfFeatureMap(
                    mean=arrays['map_mean'].astype(np.float32),
                    projection=arrays['map_projection'].astype(np.float32),
                    landmarks=arrays['map_landmarks'].astype(np.float32),
                    gamma=float(arrays['map_gamma']))
            return cls(weights=arrays['weights'].astype(np.float32),
                       intercepts=arrays['intercepts'].astype(np.float32),
                       class_ids=arrays['class_ids'].astype(np.int64),
                       hog_params=hog_params, kind=str(arrays['kind']),
                       reject_margin=float(arrays['reject_margin']),
                       info=json.loads(str(arrays['info'])), shape_params=shape_params,
                       shape_fill=None if shape_params is None else
                       arrays['shape_fill'].astype(np.float32), feature_map=feature_map,
                       margin_scale=float(arrays.get('margin_scale', 0.0)))
        except (KeyError, ValueError, TypeError) as error:
            raise ModelFileError(f'{path} is a corrupt classifier model: {error}') from None


def _make_learner(params: ClassifierParams, seed: int):
    from sklearn.linear_model import Perceptron, SGDClassifier

    if params.kind == 'sgd':
        return SGDClassifier(loss='hinge', penalty='l2', alpha=params.alpha,
                             learning_rate='optimal', average=params.average,
                             random_state=seed)
    if params.kind == 'perceptron':
        if params.average:  # scikit-learn's Perceptron is this SGDClassifier, without averaging
            return SGDClassifier(loss='perceptron', penalty=None, learning_rate='constant',
                                 eta0=1.0, average=True, random_state=seed)
        return Perceptron(random_state=seed)
    return SGDClassifier(loss='hinge', penalty=None, learning_rate=params.kind,
                         eta0=params.pa_c, average=params.average, random_state=seed)


class OnlineTrainer:
    """Online (mini-batch) training of one linear model; call :meth:`partial_fit` repeatedly.

    Args:
        class_ids: all object ids the model will know, fixed up front.
        params: learner settings.
        feature_mean, feature_scale: (D,) standardisation applied before learning (and folded
            into the weights of :meth:`model`); None for identity.
        seed: random state of the learner.
    """

    def __init__(self, class_ids: np.ndarray, *, params: ClassifierParams = ClassifierParams(),
                 feature_mean: np.ndarray | None = None,
                 feature_scale: np.ndarray | None = None, seed: int = 0) -> None:
        self.class_ids = np.unique(np.asarray(class_ids, dtype=np.int64))
        if len(self.class_ids) < 2:
            raise ValueError('need at least 2 classes to train a classifier')
        if UNKNOWN_ID in self.class_ids:
            raise ValueError(f'class id {UNKNOWN_ID} is reserved for "unknown"')
        self.params = params
        self._mean = feature_mean
        self._scale = feature_scale
        self._learner = _make_learner(params, seed)
        self.samples_seen = 0

    def _standardise(self, features: np.ndarray) -> np.ndarray:
        if self._mean is not None:
            features = features - self._mean
        if self._scale is not None:
            features = features / self._scale
        return features

    def partial_fit(self, features: np.ndarray, labels: np.ndarray) -> None:
        """One online step on (N, D) float32 descriptors and their (N,) object ids."""
        labels = np.asarray(labels, dtype=np.int64)
        unknown = np.setdiff1d(labels, self.class_ids)
        if unknown.size:
            raise ValueError(f'labels {unknown.tolist()} are not among the trainer class_ids')
        self._learner.partial_fit(self._standardise(np.asarray(features, np.float32)), labels,
                                  classes=self.class_ids)
        self.samples_seen += len(labels)

    def fit(self, features: np.ndarray, labels: np.ndarray) -> None:
        """Batch training on all (N, D) descriptors at once: ``params.epochs`` shuffled passes
        of the learner's own ``fit``, from scratch.

        Used for the feature-map models: on their Nyström features the averaged learners
        reach much better weights through ``fit`` than through many mini-batch
        ``partial_fit`` calls (PA-I: 93.9 against 88.1 % of held-out scene crops, README).
        """
        labels = np.asarray(labels, dtype=np.int64)
        unknown = np.setdiff1d(labels, self.class_ids)
        if unknown.size:
            raise ValueError(f'labels {unknown.tolist()} are not among the trainer class_ids')
        if np.setdiff1d(self.class_ids, labels).size:
            raise ValueError('batch training needs samples of every class')
        self._learner.set_params(max_iter=self.params.epochs, tol=None, shuffle=True)
        self._learner.fit(self._standardise(np.asarray(features, np.float32)), labels)
        self.samples_seen += len(labels) * self.params.epochs

    def model(self, hog_params: HogParams, *, info: dict | None = None,
              shape_params: ShapeParams | None = None,
              shape_fill: np.ndarray | None = None,
              feature_map: RbfFeatureMap | None = None,
              whitening: np.ndarray | None = None) -> LinearClassifier:
        """The current weights as a :class:`LinearClassifier` (standardisation folded in).

        With ``feature_map``, the learner saw ``feature_map.transform(x) @ whitening``; the
        (M, M) ``whitening`` is folded into the weights too.
        """
        if self.samples_seen == 0:
            raise ValueError('nothing learnt yet: call partial_fit or fit first')
        coef = np.asarray(self._learner.coef_, dtype=np.float64)
        intercept = np.asarray(self._learner.intercept_, dtype=np.float64)
        if coef.shape[0] == 1:  # binary: scikit-learn keeps one hyperplane for class 1
            coef = np.vstack([-coef, coef])
            intercept = np.concatenate([-intercept, intercept])
        weights = coef.T  # (D, C)
        if self._scale is not None:
            weights = weights / self._scale[:, None]
        if self._mean is not None:
            intercept = intercept - self._mean @ weights
        if whitening is not None:
            weights = np.asarray(whitening, np.float64) @ weights
        return LinearClassifier(weights=weights.astype(np.float32),
                                intercepts=intercept.astype(np.float32),
                                class_ids=self.class_ids.copy(), hog_params=hog_params,
                                kind=self.params.kind, reject_margin=self.params.reject_margin,
                                info=dict(info or {}), shape_params=shape_params,
                                shape_fill=shape_fill, feature_map=feature_map)


def train_classifier(features: np.ndarray, labels: np.ndarray, *,
                     hog_params: HogParams | None = None,
                     params: ClassifierParams = ClassifierParams(), seed: int = 0,
                     on_batch: Callable[[int], None] | None = None,
                     shape_params: ShapeParams | None = None) -> LinearClassifier:
    """Fit a linear model on in-memory descriptors with shuffled mini-batch epochs.

    Args:
        features: (N, D) float32 descriptors: HOG (D = ``hog_params.feature_dim``), followed
            by the shape vector when ``shape_params`` is given (NaN rows of the shape part =
            no usable depth; they get the training mean, which becomes ``shape_fill``).
        labels: (N,) int object ids (> 0).
        hog_params: stored in the model so inference normalises crops the same way
            (default ``HogParams()``).
        params: learner settings.
        seed: seeds the shuffling and the learner; same inputs and seed give the same model.
        on_batch: called with the number of samples learnt after each ``partial_fit`` (with a
            feature map: once, with ``epochs * N``, after ``fit``), e.g. a progress bar.
        shape_params: the shape feature settings ("ours"), or None for HOG only ("paper").

    Returns:
        The trained :class:`LinearClassifier`.
    """
    hog_params = HogParams() if hog_params is None else hog_params
    features = np.asarray(features, dtype=np.float32)
    labels = np.asarray(labels, dtype=np.int64)
    if features.ndim != 2 or labels.shape != (features.shape[0],):
        raise ValueError(f'need (N, D) features and (N,) labels, got {features.shape} and '
                         f'{labels.shape}')
    hog_dim = hog_params.feature_dim
    expected = hog_dim + (0 if shape_params is None else shape_params.feature_dim)
    if features.shape[1] != expected:
        raise ValueError(f'features have {features.shape[1]} values but hog_params (and '
                         f'shape_params) give {expected}')
    shape_fill = None
    if shape_params is not None:
        shape = features[:, hog_dim:]
        known = np.isfinite(shape).all(axis=1)
        shape_fill = (shape[known].mean(axis=0) if known.any()
                      else np.zeros(shape.shape[1])).astype(np.float32)
        if not known.all():
            features = features.copy()
            features[~known, hog_dim:] = shape_fill
    descriptors = features  # as the model will see them at inference (shape gaps filled)
    mean = scale = None
    if params.standardise:
        mean = features.mean(axis=0)
        scale = np.maximum(features.std(axis=0), 1e-3).astype(np.float32)
        if shape_params is not None:
            scale[:hog_dim] /= params.hog_weight
    feature_map = whitening = None
    if params.kernel_components:
        if mean is None or scale is None:
            raise ValueError('a feature map (kernel_components > 0) needs standardise=True')
        feature_map, whitening = fit_rbf_map(
            (features - mean) / scale, mean=mean, scale=scale,
            components=min(params.kernel_components, len(labels)),
            axes=min(params.kernel_axes, features.shape[1]), gamma=params.kernel_gamma,
            seed=seed)
        features = feature_map.transform(features) @ whitening
        # The Nyström features' scales span orders of magnitude (the kernel's eigenvalues);
        # the online learners converge far better on them standardised.
        mean = features.mean(axis=0)
        scale = np.maximum(features.std(axis=0), 1e-6).astype(np.float32)
    trainer = OnlineTrainer(labels, params=params, feature_mean=mean, feature_scale=scale,
                            seed=seed)
    if params.kernel_components:
        trainer.fit(features, labels)
        if on_batch is not None:
            on_batch(params.epochs * len(labels))
    else:
        rng = np.random.default_rng(seed)
        for _ in range(params.epochs):
            order = rng.permutation(len(labels))
            for start in range(0, len(order), params.batch_size):
                batch = order[start:start + params.batch_size]
                trainer.partial_fit(features[batch], labels[batch])
                if on_batch is not None:
                    on_batch(len(batch))
    model = trainer.model(hog_params, info={'samples': int(len(labels)), 'seed': int(seed),
                                            'epochs': params.epochs},
                          shape_params=shape_params, shape_fill=shape_fill,
                          feature_map=feature_map, whitening=whitening)
    scale, accuracy = _training_fit(model, descriptors, labels)
    return replace(model, margin_scale=scale,
                   info=dict(model.info, train_accuracy=round(accuracy, 4)))


def _training_fit(model: LinearClassifier, features: np.ndarray, labels: np.ndarray, *,
                  chunk: int = 4096) -> tuple[float, float]:
    """(median margin, accuracy) of ``model`` on its (N, D) training descriptors, scored in
    chunks so that a feature map's (chunk, M) block stays small."""
    margins, right = [], 0
    for start in range(0, len(features), chunk):
        prediction = model.predict_scores(model.decision_function(features[start:start + chunk]))
        margins.append(prediction.margins)
        right += int(np.sum(prediction.class_ids == labels[start:start + chunk]))
    return float(np.median(np.concatenate(margins))), right / len(labels)


def _mask_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    mask = np.ascontiguousarray(mask)
    x, y, w, h = cv2.boundingRect(mask.view(np.uint8) if mask.dtype == bool
                                  else (mask != 0).astype(np.uint8))
    if w == 0 or h == 0:
        raise ValueError('a region mask is empty: nothing to describe')
    return x, y, w, h


def _box_mask(box, shape: tuple[int, int]) -> np.ndarray:
    x, y, w, h = (int(round(float(v))) for v in box)
    mask = np.zeros(shape, bool)
    mask[max(y, 0):max(y + h, 0), max(x, 0):max(x + w, 0)] = True
    return mask


LOADERS[FILE_MAGIC] = LinearClassifier.load
