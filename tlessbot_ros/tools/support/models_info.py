"""BOP models_info.json for the commands: symmetries read for scoring, entries written
(geometry and symmetries).

The per-entry symmetry parser is :func:`tlessbot_ros.core.common.symmetries_from_models_info`;
this module only reads the file around it and writes the geometry (mm, as in BOP).
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING

from tlessbot_ros.core.common import (
    Symmetries,
    detect_symmetries,
    symmetries_from_models_info,
    symmetries_to_models_info,
)
from tlessbot_ros.errors import ModelFileError

if TYPE_CHECKING:
    from tlessbot_ros.io.models import ObjectModel


def load_symmetries(path: str | Path) -> dict[int, Symmetries]:
    """{obj_id: Symmetries} from a BOP models_info.json."""
    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f'models_info not found: {path}')
    try:
        info = json.loads(path.read_text(encoding='utf-8'))
        return {int(k): symmetries_from_models_info(v) for k, v in info.items()}
    except (ValueError, TypeError, AttributeError) as error:
        raise ModelFileError(f'{path} is not a BOP models_info.json: {error}') from None


def packaged_symmetries() -> dict[int, Symmetries]:
    """{obj_id: Symmetries} from the packaged models_info.json ({} if missing)."""
    from tlessbot_ros.data import DEFAULT_MODELS_INFO

    if not DEFAULT_MODELS_INFO.is_file():
        return {}
    return load_symmetries(DEFAULT_MODELS_INFO)


def model_geometry_mm(model: ObjectModel) -> dict[str, float]:
    """The geometry of a models_info.json entry: ``diameter``, ``min_x/y/z`` and
    ``size_x/y/z`` of the model, millimetres (unrounded)."""
    low = model.vertices.min(axis=0) * 1000.0
    size = model.extent_m * 1000.0
    return {'diameter': model.diameter_m * 1000.0,
            'min_x': low[0], 'min_y': low[1], 'min_z': low[2],
            'size_x': size[0], 'size_y': size[1], 'size_z': size[2]}


def model_symmetries(model: ObjectModel) -> Symmetries:
    """The model's listed symmetries, or detected ones when the files list none."""
    listed = model.listed_symmetries()
    if listed is None:
        return detect_symmetries(model.vertices, model.faces, diameter=model.diameter_m)
    return listed


def models_info_entry(model: ObjectModel, symmetries: Symmetries) -> dict:
    """One BOP models_info.json entry (mm, rounded to 0.1 µm): geometry and symmetries."""
    entry = {key: round(float(value), 4) for key, value in model_geometry_mm(model).items()}
    entry.update(symmetries_to_models_info(symmetries))
    return entry
