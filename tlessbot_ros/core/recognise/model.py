"""What the pipeline and the classifier node need of a classifier: the seam for new models.

:class:`~tlessbot_ros.core.recognise.classifier.LinearClassifier` is the one shipped: inference
in :mod:`~tlessbot_ros.core.recognise.classifier`, training in
:mod:`~tlessbot_ros.core.recognise.training`, its ``.npz`` file in
:mod:`~tlessbot_ros.core.recognise.model_file`.

To add a kind of model (a kernel SVM, a small network):

1. implement :class:`Classifier` (a module of this package, e.g. ``kernel_classifier.py``);
2. give its model file its own ``magic`` entry (read it with :func:`read_model_arrays`, so
   ``allow_pickle=False`` and the ``ModelFileError`` messages hold) and, at the end of the
   module that reads the file, register the reader: ``LOADERS[MY_MAGIC] = load_my_model``
   (as ``classifier.py`` does for ``LinearClassifier``);
3. add that module's name to :data:`_REGISTERING` below, so that :func:`load_classifier`
   imports it (and so registers the reader) before it looks the magic up;
4. export the new names in this package's ``__init__.py`` (``_HOME``).

:func:`load_classifier` then reads either kind from a path, and nothing above this package
changes.
"""
from __future__ import annotations

import importlib
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np

from tlessbot_ros.errors import ModelFileError

if TYPE_CHECKING:
    from tlessbot_ros.core.recognise.classifier import Prediction

UNKNOWN_ID = 0  # T-LESS ids start at 1
# A class learnt from crops of table and neighbours' fragments (no part of the set in the box);
# a crop it wins is reported as UNKNOWN_ID, and it is never a candidate part.
BACKGROUND_ID = -1


class Classifier(Protocol):
    """A trained model that names the part in each region of an image.

    Attributes:
        class_ids: (C,) int64 object ids of the score columns.
        uses_depth: whether :meth:`describe` reads the aligned depth (``depth_m``, ``K``,
            ``T_world_camera``); without them such a model falls back to its image part.
        margin_scale: median best-minus-second score margin on the model's own training crops
            (0 = unknown), the unit in which the pipeline judges how sure a margin is.
    """

    @property
    def class_ids(self) -> np.ndarray: ...

    @property
    def margin_scale(self) -> float: ...

    @property
    def uses_depth(self) -> bool: ...

    def describe(self, image: np.ndarray, masks: list[np.ndarray] | None = None,
                 boxes: Sequence[Sequence[float]] | None = None, *,
                 depth_m: np.ndarray | None = None,
                 K: np.ndarray | None = None,
                 T_world_camera: np.ndarray | None = None) -> np.ndarray:
        """(N, D) float32 descriptors of N regions of an (H, W, 3) uint8 RGB image."""

    def decision_function(self, features: np.ndarray) -> np.ndarray:
        """(N, C) float32 class scores of (N, D) descriptors."""

    def predict_scores(self, scores: np.ndarray, *,
                       reject_margin: float | None = None) -> Prediction:
        """A :class:`~tlessbot_ros.core.recognise.classifier.Prediction` from (N, C) scores."""

    def ranked_classes(self, scores: np.ndarray, k: int) -> np.ndarray:
        """(N, k) int64 object ids, best first."""


# file magic -> loader; filled by the modules that read model files, when imported
LOADERS: dict[str, Callable[[Path], Classifier]] = {}

# modules of this package that register a loader in LOADERS when imported
_REGISTERING = ('classifier',)


def read_model_arrays(path: str | Path, keys: tuple[str, ...] | None = None
                      ) -> dict[str, np.ndarray]:
    """The arrays of a model ``.npz`` (all, or those of ``keys`` it holds), read with
    ``allow_pickle=False``; ``ModelFileError`` if it is missing or not a readable ``.npz``."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f'classifier model {path} does not exist')
    try:
        with np.load(path, allow_pickle=False) as data:
            names = data.files if keys is None else [key for key in keys if key in data.files]
            return {key: data[key] for key in names}
    except Exception as error:  # OSError, ValueError (pickled), EOFError, BadZipFile and friends
        raise ModelFileError(f'{path} is not a readable classifier .npz ({error})') from None


def file_magic(path: str | Path) -> str:
    """The ``magic`` entry of a model ``.npz`` (read with ``allow_pickle=False``); '' if none."""
    return str(read_model_arrays(path, ('magic',)).get('magic', ''))


def load_classifier(path: str | Path) -> Classifier:
    """Any registered kind of classifier from its model file; ``ModelFileError`` otherwise."""
    for module in _REGISTERING:
        importlib.import_module(f'{__package__}.{module}')
    magic = file_magic(path)
    loader = LOADERS.get(magic)
    if loader is None:
        raise ModelFileError(f'{path} is not a tlessbot classifier model (magic {magic!r}, '
                             f"known: {sorted(LOADERS)}); make one with 'tlessbot train'")
    return loader(Path(path))
