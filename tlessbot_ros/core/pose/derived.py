"""What the pose stage derives from a template database before its first frame, as arrays.

Building every object's nearest-sample grid and every template's normals and FPFH takes most
of a pose node's start (docs/bench/results-2026-12-04.md), and the pose worker process does it
again. :func:`derived_arrays` exports them
(building what is missing) and :func:`restore_derived` puts them back into a freshly loaded
database, so a second start reads ~50 MB instead (where they are kept is
:mod:`tlessbot_ros.io.cache`'s business). Restored values are the built ones, bit for bit.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from tlessbot_ros.core.pose.database import NearestGrid, TemplateDatabase
from tlessbot_ros.core.pose.resting import RESTING_KEY, stable_directions

DERIVED_VERSION = 3
# the derived turn listings kept too (0.4-1 s a part at start-up): keys of a name and numbers;
# and every meshed part's stable poses (the resting-pose prior, core/pose/resting.py)
CACHED_LISTINGS = ('near_turns', 'self_half_turns', RESTING_KEY[0])


def derived_arrays(database: TemplateDatabase, *, fingerprint: str) -> dict[str, np.ndarray]:
    """Every object's default nearest grid and every template's normals and FPFH (built now
    where missing) as flat arrays for ``np.savez``; ``fingerprint`` names the templates file
    they belong to (e.g. its SHA-256), checked by :func:`restore_derived`."""
    arrays: dict[str, np.ndarray] = {'version': np.array(DERIVED_VERSION),
                                     'fingerprint': np.array(fingerprint)}
    for obj_id, obj in database.objects.items():
        grid = obj.nearest_grid()
        arrays[f'{obj_id}/grid_origin'] = np.asarray(grid.origin, np.float64)
        arrays[f'{obj_id}/grid_spacing'] = np.array(grid.spacing)
        arrays[f'{obj_id}/grid_index'] = grid.index
        arrays[f'{obj_id}/grid_distance'] = grid.distance
        for index in range(len(obj.templates)):
            normals, fpfh = obj.features(index)
            arrays[f'{obj_id}/{index}/normals'] = normals
            arrays[f'{obj_id}/{index}/fpfh'] = fpfh
        stable_directions(obj)   # the part's own: built now where missing
        for key, value in obj.derived_items().items():
            if isinstance(key, tuple) and key and key[0] in CACHED_LISTINGS and \
                    isinstance(value, np.ndarray):
                name = '|'.join([key[0], *(repr(k) for k in key[1:])])
                arrays[f'{obj_id}/listing/{name}'] = value
    return arrays


def _listings(arrays: Mapping[str, np.ndarray], obj_id: int
              ) -> dict[tuple[str | float, ...], np.ndarray]:
    """The turn listings of ``obj_id`` among ``arrays``, by their :meth:`derived` key."""
    prefix = f'{obj_id}/listing/'
    out = {}
    for name in list(arrays.keys()):
        if name.startswith(prefix):
            first, *numbers = name[len(prefix):].split('|')
            if first in CACHED_LISTINGS:
                key = (first,) + tuple(float(x) for x in numbers)
                out[key] = np.asarray(arrays[name], np.float64)
    return out


def restore_derived(database: TemplateDatabase, arrays: Mapping[str, np.ndarray], *,
                    fingerprint: str) -> bool:
    """Put arrays from :func:`derived_arrays` back into ``database``; False (and nothing
    changed) when they belong to another templates file, version or object set."""
    try:
        if int(arrays['version']) != DERIVED_VERSION or \
                str(arrays['fingerprint']) != fingerprint:
            return False
        grids, features, listings = {}, {}, {}
        for obj_id, obj in database.objects.items():
            listings[obj_id] = _listings(arrays, obj_id)
            grids[obj_id] = NearestGrid(
                np.asarray(arrays[f'{obj_id}/grid_origin'], np.float64),
                float(arrays[f'{obj_id}/grid_spacing']),
                np.asarray(arrays[f'{obj_id}/grid_index'], np.int32),
                np.asarray(arrays[f'{obj_id}/grid_distance'], np.float32))
            for index, template in enumerate(obj.templates):
                normals = np.asarray(arrays[f'{obj_id}/{index}/normals'], np.float32)
                fpfh = np.asarray(arrays[f'{obj_id}/{index}/fpfh'], np.float32)
                if normals.shape != template.points.shape or len(fpfh) != len(normals):
                    return False
                features[obj_id, index] = normals, fpfh
    except (KeyError, ValueError, TypeError):
        return False
    for obj_id, grid in grids.items():
        database[obj_id].adopt_nearest_grid(grid)
        for key, value in listings[obj_id].items():
            database[obj_id].adopt_derived(key, value)
    for (obj_id, index), (normals, fpfh) in features.items():
        template = database[obj_id].templates[index]
        template.normals, template.fpfh = normals, fpfh
    return True
