"""The cues of every foreground blob that the depth cue finds on under half of it, with the
pipeline's own parameters (``key=value`` changes them; ``colour_edge_pattern_share=0`` shows
the blobs main's rules keep): whether it lies on a part (>= 30 % on a ground-truth visible
mask) or bare table (< 5 %), its area, depth share, outline step share and common colour (the
outline rule's values), its pattern share (``colour_edge.pattern_colour_share``; with the
squares' blurred edges, ``blend_pattern_share`` within 1, 2 and 3 px), and its median height,
the table's median height and 1.48 MAD around it (the window one part length around, off
every blob) and the first's distance from the second in the third.
docs/bench/checker-false-parts.md, docs/bench/smoothed-false-parts-now.md.

    python scripts/checker_piece_cues.py SCENES TEMPLATES [VIEW] [key=value ...]
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
    blend_pattern_share,
    colour_share_around,
    outline_step_share,
    pattern_colour_share,
)
from tlessbot_ros.core.localise.cues import height_above_table
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase

sys.path.insert(0, str(Path(__file__).parent))
from outline_step_cues import window  # noqa: E402
from table_false_parts_cues import (  # noqa: E402
    OFF_PART,
    ON_PART,
    segmentations,
    truth_mask,
    two_view_frames,
)

BLEND_REACH_PX = (1, 2, 3)
COLUMNS = ('frame', 'view', 'label', 'area', 'depth_share', 'step', 'common', 'pattern',
           'blend1', 'blend2', 'blend3', 'h_mm', 'table_mm', 'noise_mm', 'z')


def blob_rows(image, seg, params) -> list[tuple]:
    """The rows of ``seg``'s foreground blobs of at least half ``min_area_px`` that the depth
    cue finds on under half of them."""
    tol = params.colour_edge_floors * np.array([params.grey_floor, params.lab_floor,
                                                params.lab_floor])
    longest = max((extent[2] for extent in params.whole_parts or ()), default=0.0)
    lab = rgb_to_lab(image.rgb)
    height = height_above_table(image.depth_m, np.asarray(image.intrinsics.K),
                                image.T_world_camera)
    depth = cv2.resize(seg.cues['depth'].view(np.uint8), image.rgb.shape[1::-1],
                       interpolation=cv2.INTER_NEAREST).astype(bool)
    truth = truth_mask(image)
    count, blobs, stats, _ = cv2.connectedComponentsWithStats(seg.foreground.view(np.uint8),
                                                              connectivity=8)
    rows = []
    for i in range(1, count):
        near = window(stats[i, :4], OUTLINE_REACH_PX + 4, blobs.shape)
        blob = blobs[near] == i
        if stats[i, cv2.CC_STAT_AREA] < params.min_area_px // 2 or depth[near][blob].mean() >= 0.5:
            continue
        around = window(stats[i, :4], int(np.ceil(longest)) + 1, blobs.shape)
        on = truth[near][blob].mean()
        off_blobs = blobs[around] == 0
        table = height[around][off_blobs & np.isfinite(height[around])]
        level = np.median(table)
        noise = 1.48 * np.median(np.abs(table - level))
        top = np.nanmedian(height[near][blob])
        label = 'part' if on >= ON_PART else 'table' if on < OFF_PART else 'mixed'
        rows.append((image.im_id, label,
                     stats[i, cv2.CC_STAT_AREA], depth[near][blob].mean(),
                     outline_step_share(lab[near], blob, tol, OUTLINE_REACH_PX),
                     colour_share_around(lab[around], blobs[around] == i, tol),
                     pattern_colour_share(lab[around], blobs[around] == i, off_blobs, tol),
                     *(blend_pattern_share(lab[around], blobs[around] == i, off_blobs, tol, r)
                       for r in BLEND_REACH_PX),
                     1e3 * top, 1e3 * level, 1e3 * noise, (top - level) / noise))
    return rows


def main(argv: list[str]) -> int:
    scenes, templates = argv[:2]
    only = argv[2] if len(argv) > 2 and '=' not in argv[2] else None
    changes = dict(a.split('=', 1) for a in argv[2:] if '=' in a)
    base = SegmentationParams()
    params = SegmentationParams(**{k: type(getattr(base, k))(v) for k, v in changes.items()})
    pipeline = None
    print('\t'.join(COLUMNS))
    for images, views, rig in two_view_frames(scenes):
        if pipeline is None:
            pipeline = PerceptionPipeline(rig=rig, templates=TemplateDatabase.load(templates),
                                          segmentation=params)
        for v, (seg, kw) in segmentations(pipeline, views).items():
            if only is None or v == only:
                for frame, *row in blob_rows(images[v], seg, kw['params']):
                    cells = [f'{x:.2f}' if isinstance(x, (float, np.floating)) else str(x)
                             for x in row]
                    print('\t'.join([str(frame), v] + cells), flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
