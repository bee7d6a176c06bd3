"""What the pose stage derives from a template database before its first frame, as arrays.

Building every object's nearest-sample grid and every template's normals and FPFH takes most
of a pose node's start (about 15 s of 17 on a 2-core machine: FPFH of 276 templates 11 s, 23
grids 5 s), and the pose worker process does it again. :func:`derived_arrays` exports them
(building what is missing) and :func:`restore_derived` puts them back into a freshly loaded
database, so a second start reads ~50 MB instead (where they are kept is
:mod:`tlessbot_ros.io.cache`'s business). Restored values are the built ones, bit for bit.
"""
from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from tlessbot_ros.core.pose.database import NearestGrid, TemplateDatabase

DERIVED_VERSION = 1


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
    return arrays


def restore_derived(database: TemplateDatabase, arrays: Mapping[str, np.ndarray], *,
                    fingerprint: str) -> bool:
    """Put arrays from :func:`derived_arrays` back into ``database``; False (and nothing
    changed) when they belong to another templates file, version or object set."""
    try:
        if int(arrays['version']) != DERIVED_VERSION or \
                str(arrays['fingerprint']) != fingerprint:
            return False
        grids, features = {}, {}
        for obj_id, obj in database.objects.items():
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
    for (obj_id, index), (normals, fpfh) in features.items():
        template = database[obj_id].templates[index]
        template.normals, template.fpfh = normals, fpfh
    return True
