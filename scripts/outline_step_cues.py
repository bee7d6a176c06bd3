"""The outline rule's two values (``SegmentationParams.colour_edge_outline_share``) for every
foreground blob of both views, with the pipeline's own parameters but that rule off: whether it
lies on a part (>= 30 % on a ground-truth visible mask) or on bare table (< 5 %), its share of
depth candidates, the share of its outline where the colour steps and the share of the window
one part length around it that has its colour. docs/bench/smoothed-localiser.md.

    python scripts/outline_step_cues.py SCENES TEMPLATES
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core.localise import SegmentationParams
from tlessbot_ros.core.localise.colour import rgb_to_lab
from tlessbot_ros.core.localise.colour_edge import (
    OUTLINE_REACH_PX,
    colour_share_around,
    outline_step_share,
)
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


def window(box: np.ndarray, pad: int, shape: tuple[int, ...]) -> tuple[slice, slice]:
    x, y, w, h = (int(v) for v in box)
    return (slice(max(y - pad, 0), min(y + h + pad, shape[0])),
            slice(max(x - pad, 0), min(x + w + pad, shape[1])))


def blob_rows(image, seg, params) -> list[str]:
    """One line per blob of ``seg``'s foreground of at least half ``min_area_px``."""
    floors = np.array([params.grey_floor, params.lab_floor, params.lab_floor])
    longest = max((extent[2] for extent in params.whole_parts or ()), default=0.0)
    lab = rgb_to_lab(image.rgb)
    depth = cv2.resize(seg.cues['depth'].view(np.uint8), image.rgb.shape[1::-1],
                       interpolation=cv2.INTER_NEAREST).astype(bool)
    truth = truth_mask(image)
    count, blobs, stats, _ = cv2.connectedComponentsWithStats(seg.foreground.view(np.uint8),
                                                              connectivity=8)
    rows = []
    for i in range(1, count):
        if stats[i, cv2.CC_STAT_AREA] < params.min_area_px // 2:
            continue
        near = window(stats[i, :4], OUTLINE_REACH_PX + 4, blobs.shape)
        around = window(stats[i, :4], int(np.ceil(longest)) + 1, blobs.shape)
        blob = blobs[near] == i
        on = truth[near][blob].mean()
        label = 'part' if on >= ON_PART else 'table' if on < OFF_PART else 'mixed'
        rows.append(f'{label}\t{stats[i, cv2.CC_STAT_AREA]}\t{depth[near][blob].mean():.2f}'
                    f'\t{outline_step_share(lab[near], blob, floors, OUTLINE_REACH_PX):.2f}'
                    f'\t{colour_share_around(lab[around], blobs[around] == i, floors):.2f}')
    return rows


def main(argv: list[str]) -> int:
    scenes, templates = argv[:2]
    pipeline = None
    print('frame\tview\tlabel\tarea\tdepth_share\tstep_share\tcommon_colour')
    for images, views, rig in two_view_frames(scenes):
        if pipeline is None:
            pipeline = PerceptionPipeline(
                rig=rig, templates=TemplateDatabase.load(templates),
                segmentation=SegmentationParams(colour_edge_outline_share=0.0))
        for v, (seg, kw) in segmentations(pipeline, views).items():
            for row in blob_rows(images[v], seg, kw['params']):
                print(f"{images['top'].im_id}\t{v}\t{row}")
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
