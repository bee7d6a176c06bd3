"""Stage 2, recognition: HOG and metric shape features of a region, the RBF feature map and
the linear classifiers over them.

Modules: :mod:`.hog` (crops and HOG), :mod:`.shape` (metric shape features), :mod:`.feature_map`
(Nyström RBF map), :mod:`.classifier` (``LinearClassifier`` inference), :mod:`.training` (its
learners), :mod:`.model_file` (its ``.npz`` file) and :mod:`.model` (the ``Classifier`` protocol
and ``load_classifier``: where a new kind of model plugs in).

This package's public API; names load on first use, so importing one light module
(geometry, say) does not import Open3D."""
from __future__ import annotations

from typing import TYPE_CHECKING

from tlessbot_ros.lazy import lazy_api

# name -> the module of this package that defines it
_HOME = {
    'LinearClassifier': 'classifier',
    'Prediction': 'classifier',
    'EIGEN_CUTOFF': 'feature_map',
    'RbfFeatureMap': 'feature_map',
    'fit_rbf_map': 'feature_map',
    'HogParams': 'hog',
    'describe_regions': 'hog',
    'hog_features': 'hog',
    'normalise_crop': 'hog',
    'BACKGROUND_ID': 'model',
    'Classifier': 'model',
    'LOADERS': 'model',
    'UNKNOWN_ID': 'model',
    'file_magic': 'model',
    'load_classifier': 'model',
    'read_model_arrays': 'model',
    'FILE_MAGIC': 'model_file',
    'FORMAT_VERSION': 'model_file',
    'load_linear_classifier': 'classifier',
    'save_linear_classifier': 'classifier',
    'ShapeParams': 'shape',
    'region_points_world': 'shape',
    'shape_features': 'shape',
    'shape_features_batch': 'shape',
    'KINDS': 'training',
    'ClassifierParams': 'training',
    'OnlineTrainer': 'training',
    'train_classifier': 'training',
}
__all__ = sorted(_HOME)

__getattr__, __dir__ = lazy_api(__name__, _HOME)

if TYPE_CHECKING:
    from tlessbot_ros.core.recognise.classifier import (  # noqa: F401
        LinearClassifier,
        Prediction,
        load_linear_classifier,
        save_linear_classifier,
    )
    from tlessbot_ros.core.recognise.feature_map import (  # noqa: F401
        EIGEN_CUTOFF,
        RbfFeatureMap,
        fit_rbf_map,
    )
    from tlessbot_ros.core.recognise.hog import (  # noqa: F401
        HogParams,
        describe_regions,
        hog_features,
        normalise_crop,
    )
    from tlessbot_ros.core.recognise.model import (  # noqa: F401
        BACKGROUND_ID,
        LOADERS,
        UNKNOWN_ID,
        Classifier,
        file_magic,
        load_classifier,
        read_model_arrays,
    )
    from tlessbot_ros.core.recognise.model_file import (  # noqa: F401
        FILE_MAGIC,
        FORMAT_VERSION,
    )
    from tlessbot_ros.core.recognise.shape import (  # noqa: F401
        ShapeParams,
        region_points_world,
        shape_features,
        shape_features_batch,
    )
    from tlessbot_ros.core.recognise.training import (  # noqa: F401
        KINDS,
        ClassifierParams,
        OnlineTrainer,
        train_classifier,
    )
