"""What the colour edge test (``SegmentationParams.colour_edge_floors``) drops, per view: each
frame is localised twice (the test off, then on; the pipeline's own parameters) and every
foreground blob of the first run that the second lacks is counted as on a part (>= 30 % of it
on a ground-truth visible mask of that view) or on bare table (< 5 %).
docs/bench/table-false-parts.md. With KEY=VALUE the first run sets that parameter instead
(``colour_edge_outline_share=0``: what the outline test alone drops,
docs/bench/smoothed-localiser.md).

    python scripts/table_false_parts_dropped.py SCENES TEMPLATES [FLOORS | KEY=VALUE]
"""
from __future__ import annotations

import sys
from collections import Counter
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core.localise import SegmentationParams
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase

sys.path.insert(0, str(Path(__file__).parent))
from table_false_parts_cues import (  # noqa: E402
    OFF_PART,
    ON_PART,
    segmentations,
    truth_mask,
    two_view_frames,
)

VIEWS = ('top', 'side')


def main(argv: list[str]) -> int:
    scenes, templates = argv[:2]
    first = {'colour_edge_floors': 0.0}
    floors = SegmentationParams().colour_edge_floors
    if len(argv) > 2 and '=' in argv[2]:
        key, value = argv[2].split('=', 1)
        first = {key: float(value)}
    elif len(argv) > 2:
        floors = float(argv[2])
    counts: Counter = Counter()
    pipelines = None
    for images, views, rig in two_view_frames(scenes):
        if pipelines is None:
            db = TemplateDatabase.load(templates)
            pipelines = [PerceptionPipeline(rig=rig, templates=db, segmentation=params)
                         for params in (SegmentationParams(**first),
                                        SegmentationParams(colour_edge_floors=floors))]
        off, on = ({v: seg.foreground for v, (seg, _) in segmentations(p, views).items()}
                   for p in pipelines)
        for v in VIEWS:
            truth = truth_mask(images[v])
            count, blobs = cv2.connectedComponents(off[v].view(np.uint8), connectivity=8)
            for i in range(1, count):
                blob = blobs == i
                if on[v][blob].any():
                    continue
                share = truth[blob].mean()
                kind = 'part' if share >= ON_PART else 'table' if share < OFF_PART else 'mixed'
                big = 'area >= 80' if blob.sum() >= 80 else 'area < 80'
                counts[(v, kind, big)] += 1
                if kind != 'table':
                    print(f"frame {images['top'].im_id} {v}:"
                          f' dropped a blob of {int(blob.sum())} px, '
                          f'{share:.2f} on a part')
    print(f'{scenes} (floors {floors}, first run: {first}): blobs dropped')
    for key in sorted(counts):
        print(' ', *key, counts[key])
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
