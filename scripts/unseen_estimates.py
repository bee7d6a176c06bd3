"""Poses that `tlessbot evaluate` cannot score: those whose centre lies outside the side
camera's image (only the top camera sees them there; evaluate scores in the side camera, so a
false one there is no false positive of its report). docs/bench/other-renderer.md;
``tlessbot evaluate`` now reports those near no part (unseen_parts.py).

    python scripts/unseen_estimates.py SCENES ESTIMATES_CSV [SCENES ESTIMATES_CSV ...]
"""
from __future__ import annotations

import csv
import sys
from collections import Counter

import numpy as np

from tlessbot_ros.io.bop import read_split
from tlessbot_ros.tools.support.unseen_parts import outside_image


def unseen(scenes: str, estimates: str) -> tuple[int, int, int]:
    """(frames, poses, poses whose centre projects outside the side image)."""
    images = {im.im_id: im for im in read_split(scenes, 'test_side', load_masks=False)}
    poses, outside = 0, Counter()
    with open(estimates) as f:
        for row in csv.DictReader(f):
            image = images[int(row['im_id'])]
            t = np.array(row['t'].split(), float) / 1000.0   # in the side camera
            poses += 1
            outside[image.im_id] += outside_image(image, t)
    return len(images), poses, sum(outside.values())


def main(argv: list[str]) -> int:
    for scenes, estimates in zip(argv[::2], argv[1::2]):
        frames, poses, outside = unseen(scenes, estimates)
        print(f'{estimates}: {poses} poses in {frames} frames, {outside} outside the side '
              f'image ({outside / frames:.2f} a frame)')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
