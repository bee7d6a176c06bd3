"""Where the fallback's known table changes its input: ``tlessbot evaluate`` with a line for
each call of the view-grid fallback. docs/bench/fallback-table-plane.md.

    python scripts/fallback_table_fires.py EVALUATE ARGUMENTS...

Prints ``FALLBACK <obj> <table known> <ROI points> <kept by the plane search> <kept by the
known table> <points kept by one rule only> <points by height over the table: below -3
mm, -3..0, 0..3, 3..6, 6..9, 9..12, above>`` for each call (the search as
``fallback_table_band`` 0 runs it, the known table as the tree's settings), and a total at
the end.
"""
from __future__ import annotations

import sys

import numpy as np

import tlessbot_ros.core.pose.fallback as fallback

_original = fallback.without_clutter
_EDGES_MM = [-1e9, -3.0, 0.0, 3.0, 6.0, 9.0, 12.0, 1e9]
_calls = {'calls': 0, 'table known': 0, 'input changed': 0}


def _spy(scene_c, obj, p, T_world_camera=None):
    kept = _original(scene_c, obj, p, T_world_camera)
    searched = fallback._without_wide_planes(scene_c, obj, p, p.fallback_drop_planes)
    a = {tuple(x) for x in np.round(kept, 6)}
    b = {tuple(x) for x in np.round(searched, 6)}
    differ = len(a ^ b)
    _calls['calls'] += 1
    _calls['table known'] += T_world_camera is not None
    _calls['input changed'] += differ > 0
    heights = ''
    if T_world_camera is not None:   # points by height over the table, mm: the band's reach
        T = np.asarray(T_world_camera, np.float64)
        h = 1e3 * (scene_c @ T[2, :3] + T[2, 3])
        heights = ' '.join(str(int(n)) for n in np.histogram(h, _EDGES_MM)[0])
    print('FALLBACK', getattr(obj, 'obj_id', '?'), int(T_world_camera is not None),
          len(scene_c), len(searched), len(kept), differ, heights, flush=True)
    return kept


if __name__ == '__main__':
    fallback.without_clutter = _spy
    from tlessbot_ros.tools.cli import main
    code = main(['evaluate', *sys.argv[1:]]) or 0
    print('FALLBACK TOTAL', ' '.join(f'{k.replace(" ", "_")}={v}' for k, v in _calls.items()))
    sys.exit(code)
