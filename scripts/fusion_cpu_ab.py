"""CPU time of ``fuse_views`` with the pipeline's own parameters and with one of them changed,
the two run alternately on every frame's segmentations in one process
(``time.process_time``, so the ratio holds on a shared machine), and the frames where the two
fused label images differ (where the change fires). docs/bench/smoothed-merged-parts.md.

    python scripts/fusion_cpu_ab.py SCENES TEMPLATES KEY=VALUE [REPEATS]
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from tlessbot_ros.core.localise import fuse_views
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.tools.support.overrides import apply_overrides

sys.path.insert(0, str(Path(__file__).parent))
from table_false_parts_cues import segmentations, two_view_frames  # noqa: E402


def main(argv: list[str]) -> int:
    scenes, templates, change = argv[:3]
    repeats = int(argv[3]) if len(argv) > 3 else 3
    seconds = [0.0, 0.0]
    pipeline = None
    frames, fired = 0, []
    for images, views, rig in two_view_frames(scenes, load_masks=False):
        if pipeline is None:
            pipeline = PerceptionPipeline(rig=rig, templates=TemplateDatabase.load(templates))
        seg = segmentations(pipeline, views)
        both = [pipeline.fusion, apply_overrides(pipeline.fusion, [change])]
        kw = dict(rig=rig, side_rgb=views['side'].rgb, depth_top_m=views['top'].depth_m)
        labels = []
        for _ in range(repeats):
            for k, params in enumerate(both):
                start = time.process_time()
                out = fuse_views(seg['top'][0], seg['side'][0], params=params, **kw)
                seconds[k] += time.process_time() - start
                labels.append(out)
        a, b = labels[0], labels[1]
        if any(not np.array_equal(a.labels[v], b.labels[v]) for v in ('top', 'side')):
            fired.append(f'{images["side"].im_id} ({len(a.instances)} -> {len(b.instances)})')
        frames += 1
    runs = frames * repeats
    print(f'{scenes}, {frames} frames x {repeats}: fuse_views ms a frame, own parameters '
          f'{1000 * seconds[0] / runs:.2f}, {change} {1000 * seconds[1] / runs:.2f} '
          f'(x{seconds[1] / max(seconds[0], 1e-9):.2f}); differs on frames: '
          f'{", ".join(fired) or "none"}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
