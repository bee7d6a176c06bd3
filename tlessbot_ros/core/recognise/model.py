"""What the pipeline and the classifier node need of a classifier: the seam for new models.

:class:`~tlessbot_ros.core.recognise.classifier.LinearClassifier` is the one shipped. A new kind
of model (a kernel SVM, a small network) implements :class:`Classifier` and registers a loader
for its file magic in :data:`LOADERS`; :func:`load_classifier` then reads either from a path,
and nothing above this package changes.
"""
from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Protocol

import numpy as np

from tlessbot_ros.errors import ModelFileError

UNKNOWN_ID = 0  # T-LESS ids start at 1


class Classifier(Protocol):
    """A trained model that names the part in each region of an image.

    Attributes:
        class_ids: (C,) int64 object ids of the score columns.
        uses_depth: whether :meth:`describe` reads the aligned depth (``depth_m``, ``K``,
            ``T_world_camera``); without them such a model falls back to its image part.
        margin_scale: median best-minus-second score margin on the model's own training crops
            (0 = unknown), the unit in which the pipeline judges how sure a margin is.
    """

    class_ids: np.ndarray
    margin_scale: float

    @property
    def uses_depth(self) -> bool: ...

    def describe(self, image: np.ndarray, masks: list[np.ndarray] | None = None,
                 boxes: list | None = None, *, depth_m: np.ndarray | None = None,
                 K: np.ndarray | None = None,
                 T_world_camera: np.ndarray | None = None) -> np.ndarray:
        """(N, D) float32 descriptors of N regions of an (H, W, 3) uint8 RGB image."""

    def decision_function(self, features: np.ndarray) -> np.ndarray:
        """(N, C) float32 class scores of (N, D) descriptors."""

    def predict_scores(self, scores: np.ndarray, *, reject_margin: float | None = None):
        """A :class:`~tlessbot_ros.core.recognise.classifier.Prediction` from (N, C) scores."""

    def ranked_classes(self, scores: np.ndarray, k: int) -> np.ndarray:
        """(N, k) int64 object ids, best first."""


# file magic -> loader; filled by the modules that define models
LOADERS: dict[str, Callable[[Path], Classifier]] = {}


def file_magic(path: str | Path) -> str:
    """The ``magic`` entry of a model ``.npz`` (read with ``allow_pickle=False``)."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f'classifier model {path} does not exist')
    try:
        with np.load(path, allow_pickle=False) as data:
            return str(data['magic']) if 'magic' in data.files else ''
    except (OSError, ValueError, EOFError) as error:
        raise ModelFileError(f'{path} is not a readable classifier .npz ({error})') from None
    except Exception as error:  # zipfile.BadZipFile and friends
        raise ModelFileError(f'{path} is not a readable classifier .npz ({error})') from None


def load_classifier(path: str | Path) -> Classifier:
    """Any registered kind of classifier from its model file; ``ModelFileError`` otherwise."""
    from tlessbot_ros.core.recognise import classifier as _linear  # noqa: F401  registers

    magic = file_magic(path)
    loader = LOADERS.get(magic)
    if loader is None:
        raise ModelFileError(f'{path} is not a tlessbot classifier model (magic {magic!r}, '
                             f"known: {sorted(LOADERS)}); make one with 'tlessbot train'")
    return loader(Path(path))
