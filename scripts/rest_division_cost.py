"""Same-run cost of two_parts' second division of a region's rest (issue 41).

    PYTHONPATH=. python scripts/rest_division_cost.py SEED SET   # a cell of /work/bench50

Runs every frame of the cell twice in one process, the rule on and off (off: split_off refuses
a second piece, as before), alternating which goes first, and prints the pose stage's time
per frame and the parts with a pose of each.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

import tlessbot_ros.core.two_parts as two_parts
from tlessbot_ros.core.common import SIDE, TOP, CameraMount, Rig
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.io.bop import read_split

BENCH = Path('/work/bench50')


def main() -> None:
    seed, cell = sys.argv[1], sys.argv[2]
    real = two_parts.split_off
    mode = {'old': False}

    def split_off(*args, apart_from=(), **kwargs):
        if mode['old'] and apart_from:
            return None
        return real(*args, apart_from=apart_from, **kwargs)

    two_parts.split_off = split_off
    pipeline = None
    times: dict[str, list[float]] = {'new': [], 'old': []}
    parts = {'new': 0, 'old': 0}
    scenes = BENCH / 'scenes' / seed / cell
    frames = zip(*[read_split(scenes, f'test_{v}') for v in (TOP, SIDE)])
    for n, (top, side) in enumerate(frames):
        by_view = {TOP: top, SIDE: side}
        if pipeline is None:
            rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                       for v, im in by_view.items()})
            folder = BENCH / 'parts' / cell
            pipeline = PerceptionPipeline(
                rig=rig, classifier=LinearClassifier.load(folder / 'classifier.npz'),
                templates=TemplateDatabase.load(folder / 'templates.npz'))
            pipeline.warm_up()
        inputs = {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera)
                  for v, im in by_view.items()}
        for m in (('new', 'old') if n % 2 == 0 else ('old', 'new')):
            mode['old'] = m == 'old'
            result = pipeline.process(inputs)
            times[m].append(result.timings_ms['pose'])
            parts[m] += sum(d.pose is not None for d in result.detections)
        print(n, {m: round(v[-1]) for m, v in times.items()}, flush=True)
    print(f'pose ms per frame, median: with {np.median(times["new"]):.0f}, without '
          f'{np.median(times["old"]):.0f}; parts with a pose {parts}')


if __name__ == '__main__':
    main()
