"""CPU time of ``segment`` on one view with the pipeline's own parameters and with one of them
changed, the two run alternately on every frame in one process (``time.process_time``, so the
ratio holds on a shared machine), with the instances each finds.
docs/bench/smoothed-localiser.md.

    python scripts/segment_cpu_ab.py SCENES TEMPLATES VIEW KEY=VALUE [REPEATS]
"""
from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

from tlessbot_ros.core.localise import segment
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase

sys.path.insert(0, str(Path(__file__).parent))
from table_false_parts_cues import segmentations, two_view_frames  # noqa: E402


def main(argv: list[str]) -> int:
    scenes, templates, view, change = argv[:4]
    repeats = int(argv[4]) if len(argv) > 4 else 2
    key, value = change.split('=', 1)
    seconds = [0.0, 0.0]
    found = [0, 0]
    pipeline = None
    frames = 0
    for _, views, rig in two_view_frames(scenes, load_masks=False):
        if pipeline is None:
            pipeline = PerceptionPipeline(rig=rig, templates=TemplateDatabase.load(templates))
        _, kw = segmentations(pipeline, views)[view]
        both = [kw, {**kw, 'params': dataclasses.replace(kw['params'], **{key: float(value)})}]
        for _ in range(repeats):
            for k, args in enumerate(both):
                start = time.process_time()
                seg = segment(views[view].rgb, **args)
                seconds[k] += time.process_time() - start
                found[k] += seg.count
        frames += 1
    runs = frames * repeats
    print(f'{scenes} {view}, {frames} frames x {repeats}: segment ms a frame, own parameters '
          f'{1000 * seconds[0] / runs:.1f}, {change} {1000 * seconds[1] / runs:.1f} '
          f'(x{seconds[0] / seconds[1]:.2f}); instances {found[0] / runs:.2f} / '
          f'{found[1] / runs:.2f} a frame')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
