"""What a two-view scenes folder holds, to set two scene sources side by side
(docs/bench/other-renderer.md): parts per frame, targets (visib_fract >= 0.3 in the side
camera), parts whose visible pixels touch another part's there, parts resting on another
part (lowest point above the table), and the side camera's valid depth.

    python scripts/scene_stats.py SCENES MODELS [SCENES MODELS ...]
"""
from __future__ import annotations

import sys

import cv2
import numpy as np

from tlessbot_ros.io.bop import read_split
from tlessbot_ros.io.models import load_models

TOUCH_PX = 2          # visible masks this close count as touching
ON_ANOTHER_M = 0.002  # lowest point this far above the table: resting on another part


def stats(scenes: str, models_dir: str) -> dict[str, float]:
    models = load_models(models_dir)
    parts = targets = touching = on_another = frames = 0
    valid: list[float] = []
    for image in read_split(scenes, 'test_side'):
        frames += 1
        valid.append(float(np.mean(np.isfinite(image.depth_m))))
        kernel = np.ones((2 * TOUCH_PX + 1,) * 2, np.uint8)
        masks = [gt.mask if gt.mask is not None else np.zeros(image.depth_m.shape, bool)
                 for gt in image.gt]
        for k, gt in enumerate(image.gt):
            parts += 1
            targets += (gt.visib_fract or 0) >= 0.3
            grown = cv2.dilate(masks[k].astype(np.uint8), kernel) > 0
            touching += any(np.any(grown & m) for j, m in enumerate(masks) if j != k)
            T = image.T_world_camera @ gt.T_camera_object
            lowest = (models[gt.obj_id].vertices @ T[:3, :3].T + T[:3, 3])[:, 2].min()
            on_another += lowest > ON_ANOTHER_M
    return {'frames': frames, 'parts per frame': parts / frames,
            'targets': targets / parts, 'touching': touching / parts,
            'on another': on_another / parts, 'valid depth': float(np.mean(valid))}


def main(argv: list[str]) -> int:
    for scenes, models_dir in zip(argv[::2], argv[1::2]):
        row = stats(scenes, models_dir)
        print(scenes, ', '.join(f'{k} {v:.2f}' if isinstance(v, float) else f'{k} {v}'
                                for k, v in row.items()))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
