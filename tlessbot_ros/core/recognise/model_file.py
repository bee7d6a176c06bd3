"""The model file of a :class:`~tlessbot_ros.core.recognise.LinearClassifier`: a compressed
``.npz`` of plain arrays and JSON strings, read with ``allow_pickle=False`` (a model file can
come from anywhere; unpickling one could run code).

This module knows the file, not the class: it writes a model's fields and reads them back as
the class's keyword arguments. :mod:`.classifier` builds the model from them and registers
``load_linear_classifier`` for :data:`FILE_MAGIC` in
:data:`~tlessbot_ros.core.recognise.model.LOADERS`.
"""
from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path
from typing import Any

import numpy as np

from tlessbot_ros.core.recognise.feature_map import RbfFeatureMap
from tlessbot_ros.core.recognise.hog import HogParams
from tlessbot_ros.core.recognise.model import read_model_arrays
from tlessbot_ros.core.recognise.shape import ShapeParams
from tlessbot_ros.errors import ModelFileError

FORMAT_VERSION = 3  # 2 adds shape_params / shape_fill, 3 the feature map; 1 and 2 still load
FILE_MAGIC = 'tlessbot_ros.linear_classifier'


def write_linear_classifier(path: str | Path, *, weights: np.ndarray, intercepts: np.ndarray,
                            class_ids: np.ndarray, hog_params: HogParams, kind: str,
                            reject_margin: float, info: dict[str, Any],
                            shape_params: ShapeParams | None, shape_fill: np.ndarray | None,
                            feature_map: RbfFeatureMap | None,
                            margin_scale: float) -> None:
    """Write a linear model's fields as a compressed ``.npz`` (no pickled objects).

    Keys: ``magic``, ``format_version``, ``kind``, ``weights`` (D, C) float32,
    ``intercepts`` (C,) float32, ``class_ids`` (C,) int64, ``hog_params`` (JSON),
    ``reject_margin``, ``info`` (JSON), ``shape_params`` (JSON, "null" for paper features),
    ``shape_fill`` (F,) float32 (empty for paper features), ``map_mean`` (D,) float32,
    ``map_projection`` (D, k) and ``map_landmarks`` (M, k) float16, ``map_gamma`` (all
    empty / 0 without a feature map), ``margin_scale`` (absent from older files: 0).
    """
    fmap = feature_map
    empty = np.zeros(0, np.float32)
    shape_json = json.dumps(None if shape_params is None else shape_params.to_dict())
    fill = empty if shape_fill is None else shape_fill
    np.savez_compressed(
        Path(path), magic=np.array(FILE_MAGIC), format_version=np.array(FORMAT_VERSION),
        kind=np.array(kind), weights=weights.astype(np.float32),
        intercepts=intercepts.astype(np.float32), class_ids=class_ids.astype(np.int64),
        hog_params=np.array(json.dumps(hog_params.to_dict())),
        reject_margin=np.array(float(reject_margin)),
        info=np.array(json.dumps(info)), shape_params=np.array(shape_json),
        shape_fill=np.asarray(fill, np.float32),
        map_mean=empty if fmap is None else fmap.mean,
        map_projection=empty if fmap is None else fmap.projection.astype(np.float16),
        map_landmarks=empty if fmap is None else fmap.landmarks.astype(np.float16),
        map_gamma=np.array(0.0 if fmap is None else fmap.gamma),
        margin_scale=np.array(float(margin_scale)))


def read_linear_classifier(path: str | Path) -> dict[str, Any]:
    """The fields of a model written by :func:`write_linear_classifier`, as the keyword
    arguments of ``LinearClassifier``; raises ``ModelFileError`` if it is not one (missing,
    unreadable, another magic, a newer format or corrupt)."""
    path = Path(path)
    arrays = read_model_arrays(path)
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
        return dict(weights=arrays['weights'].astype(np.float32),
                    intercepts=arrays['intercepts'].astype(np.float32),
                    class_ids=arrays['class_ids'].astype(np.int64),
                    hog_params=hog_params, kind=str(arrays['kind']),
                    reject_margin=float(arrays['reject_margin']),
                    info=json.loads(str(arrays['info'])), shape_params=shape_params,
                    shape_fill=None if shape_params is None else
                    arrays['shape_fill'].astype(np.float32), feature_map=feature_map,
                    margin_scale=float(arrays.get('margin_scale', 0.0)))
    except (KeyError, ValueError, TypeError) as error:
        raise corrupt_model(path, error) from None


def corrupt_model(path: Path, error: Exception) -> ModelFileError:
    """The error for a model file whose fields do not make a model."""
    return ModelFileError(f'{path} is a corrupt classifier model: {error}')
