"""Every part whose outcome (own_parts_why.py's: ok, none, far, tilt...) differs between two
evaluate outputs of the same scenes. docs/bench/smoothed-parts-missed.md.

    python scripts/own_parts_diff.py SCENES MODELS A/estimates.csv B/estimates.csv
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from own_parts_why import _estimates, _outcome, side_parts, symmetry_turns  # noqa: E402


def main(argv: list[str]) -> int:
    scenes, models = Path(argv[0]), Path(argv[1])
    runs = [_estimates(Path(a)) for a in argv[2:4]]
    info = json.loads((models / 'models_info.json').read_text())
    turns = symmetry_turns(info)
    for scene, im, k, part, up_c in side_parts(scenes):
        R = np.array(part['cam_R_m2c']).reshape(3, 3)
        t = np.array(part['cam_t_m2c']) / 1000
        key = (scene, im, part['obj_id'])
        a, b = (_outcome(run.get(key, []), R, t, turns[str(part['obj_id'])], up_c)
                for run in runs)
        if a != b:
            print(f'scene {scene:06d} im {im} gt {k} obj {part["obj_id"]}: {a} -> {b}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
