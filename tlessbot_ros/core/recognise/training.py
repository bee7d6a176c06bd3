"""Training of the linear classifiers: SGD, Perceptron, PA-I and PA-II.

Training uses scikit-learn's online learners through ``partial_fit`` on shuffled mini-batches
(through one ``fit`` over all samples for feature-map models, see :meth:`OnlineTrainer.fit`):

- ``'sgd'``: ``SGDClassifier`` (linear SVM, hinge loss, L2 penalty ``alpha``, optimal rate);
- ``'perceptron'``: ``Perceptron`` (Rosenblatt's rule);
- ``'pa1'`` / ``'pa2'``: Passive-Aggressive I / II of Crammer et al. [1], as
  ``SGDClassifier(loss='hinge', penalty=None, learning_rate='pa1' | 'pa2', eta0=C)``, the
  replacement of ``PassiveAggressiveClassifier`` (deprecated in scikit-learn 1.8, removed in 1.10).

The result is a :class:`~tlessbot_ros.core.recognise.LinearClassifier` (inference in
:mod:`~tlessbot_ros.core.recognise.classifier`); scikit-learn is imported only here, when a
learner is made.

References:
    [1] K. Crammer et al., "Online Passive-Aggressive Algorithms", JMLR 7, 2006.
    [2] Sensors 2020, 20, 2203 (the seed paper), §3.2, §6.1, Fig. 10.
"""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from tlessbot_ros.core.recognise.classifier import LinearClassifier
from tlessbot_ros.core.recognise.feature_map import RbfFeatureMap, fit_rbf_map
from tlessbot_ros.core.recognise.hog import HogParams
from tlessbot_ros.core.recognise.model import UNKNOWN_ID
from tlessbot_ros.core.recognise.shape import ShapeParams

KINDS = ('sgd', 'perceptron', 'pa1', 'pa2')


@dataclass(frozen=True)
class ClassifierParams:
    """Training settings.

    Attributes:
        kind: one of ``KINDS``.
        epochs: passes over the training set (each shuffled); 10 by default: with 5, SGD
            had not settled (docs/bench/code-figures.md).
        batch_size: samples per ``partial_fit`` call (the mini-batch).
        alpha: L2 regularisation of ``'sgd'`` (scikit-learn's ``alpha``).
        pa_c: aggressiveness C of PA-I / PA-II (scikit-learn's ``eta0``).
        standardise: scale each feature to zero mean and unit variance before training; the
            scaling is folded into the stored weights.
        reject_margin: default minimum margin (best minus second-best score) to accept a label;
            0 accepts everything.
        hog_weight: with shape (or box-size) features, the standardised HOG block is
            multiplied by this fixed factor before learning (a fixed map, folded into the stored
            weights): the rendered-vs-scene domain gap is larger for HOG than for the metric
            features, and a low weight keeps it from drowning them (docs/bench/code-figures.md).
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


def _make_learner(params: ClassifierParams, seed: int) -> Any:
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
        ``partial_fit`` calls (docs/design.md, Recognition).
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

    def model(self, hog_params: HogParams, *, info: dict[str, Any] | None = None,
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
        features, shape_fill = _fill_shape_gaps(features, hog_dim)
    descriptors = features  # as the model will see them at inference (shape gaps filled)
    features, mean, scale, feature_map, whitening = _learner_inputs(
        features, hog_dim=hog_params.hog_dim,
        with_shape=shape_params is not None or hog_params.box_size, samples=len(labels),
        params=params, seed=seed)
    trainer = OnlineTrainer(labels, params=params, feature_mean=mean, feature_scale=scale,
                            seed=seed)
    _run_epochs(trainer, features, labels, params=params, seed=seed, on_batch=on_batch)
    model = trainer.model(hog_params, info={'samples': int(len(labels)), 'seed': int(seed),
                                            'epochs': params.epochs},
                          shape_params=shape_params, shape_fill=shape_fill,
                          feature_map=feature_map, whitening=whitening)
    margin_scale, accuracy = _training_fit(model, descriptors, labels)
    return replace(model, margin_scale=margin_scale,
                   info=dict(model.info, train_accuracy=round(accuracy, 4)))


def _fill_shape_gaps(features: np.ndarray, hog_dim: int) -> tuple[np.ndarray, np.ndarray]:
    """(features with the NaN shape rows filled, (F,) float32 fill): the fill is the mean of
    the rows with usable depth (zeros if none), as at inference (``shape_fill``)."""
    shape = features[:, hog_dim:]
    known = np.isfinite(shape).all(axis=1)
    shape_fill = (shape[known].mean(axis=0) if known.any()
                  else np.zeros(shape.shape[1])).astype(np.float32)
    if not known.all():
        features = features.copy()
        features[~known, hog_dim:] = shape_fill
    return features, shape_fill


def _learner_inputs(features: np.ndarray, *, hog_dim: int, with_shape: bool, samples: int,
                    params: ClassifierParams, seed: int
                    ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None,
                               RbfFeatureMap | None, np.ndarray | None]:
    """What the learner sees: (features, mean, scale, feature_map, whitening).

    ``mean`` and ``scale`` (None without ``params.standardise``) standardise ``features`` in
    :class:`OnlineTrainer`; with a feature map, ``features`` are already mapped and whitened.
    """
    mean = scale = None
    if params.standardise:
        mean = features.mean(axis=0)
        scale = np.maximum(features.std(axis=0), 1e-3).astype(np.float32)
        if with_shape:
            scale[:hog_dim] /= params.hog_weight
    feature_map = whitening = None
    if params.kernel_components:
        if mean is None or scale is None:
            raise ValueError('a feature map (kernel_components > 0) needs standardise=True')
        feature_map, whitening = fit_rbf_map(
            (features - mean) / scale, mean=mean, scale=scale,
            components=min(params.kernel_components, samples),
            axes=min(params.kernel_axes, features.shape[1]), gamma=params.kernel_gamma,
            seed=seed)
        features = feature_map.transform(features) @ whitening
        # The Nyström features' scales span orders of magnitude (the kernel's eigenvalues);
        # the online learners converge far better on them standardised.
        mean = features.mean(axis=0)
        scale = np.maximum(features.std(axis=0), 1e-6).astype(np.float32)
    return features, mean, scale, feature_map, whitening


def _run_epochs(trainer: OnlineTrainer, features: np.ndarray, labels: np.ndarray, *,
                params: ClassifierParams, seed: int,
                on_batch: Callable[[int], None] | None) -> None:
    """``params.epochs`` shuffled passes of mini-batches (one batch ``fit`` with a feature
    map, see :meth:`OnlineTrainer.fit`), reporting progress to ``on_batch``."""
    if params.kernel_components:
        trainer.fit(features, labels)
        if on_batch is not None:
            on_batch(params.epochs * len(labels))
        return
    rng = np.random.default_rng(seed)
    for _ in range(params.epochs):
        order = rng.permutation(len(labels))
        for start in range(0, len(order), params.batch_size):
            batch = order[start:start + params.batch_size]
            trainer.partial_fit(features[batch], labels[batch])
            if on_batch is not None:
                on_batch(len(batch))


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

