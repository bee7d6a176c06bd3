"""Every part whose outcome (own_parts_why.py's: ok, none, far, tilt...) differs between two
evaluate outputs of the same scenes. docs/bench/smoothed-parts-missed.md.

    python scripts/own_parts_diff.py SCENES MODELS A/estimates.csv B/estimates.csv
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common.symmetry import symmetries_from_models_info

sys.path.insert(0, str(Path(__file__).resolve().parent))
from own_parts_why import _estimates, _outcome  # noqa: E402


def main(argv: list[str]) -> int:
    scenes, models = Path(argv[0]), Path(argv[1])
    runs = [_estimates(Path(a)) for a in argv[2:4]]
    info = json.loads((models / 'models_info.json').read_text())
    turns = {k: [S[:3, :3] for S in symmetries_from_models_info(v).transforms(
        step_rad=np.radians(1))] for k, v in info.items()}
    for scene in sorted((scenes / 'test_side').iterdir()):
        gt = json.loads((scene / 'scene_gt.json').read_text())
        cameras = json.loads((scene / 'scene_camera.json').read_text())
        for im, parts in gt.items():
            up_c = np.array(cameras[im]['cam_R_w2c']).reshape(3, 3) @ np.array([0, 0, 1.0])
            for k, part in enumerate(parts):
                R = np.array(part['cam_R_m2c']).reshape(3, 3)
                t = np.array(part['cam_t_m2c']) / 1000
                key = (int(scene.name), int(im), part['obj_id'])
                a, b = (_outcome(run.get(key, []), R, t, turns[str(part['obj_id'])], up_c)
                        for run in runs)
                if a != b:
                    print(f'scene {scene.name} im {im} gt {k} obj {part["obj_id"]}: {a} -> {b}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
