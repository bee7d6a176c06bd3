"""Cues of the foreground blobs the outline rule keeps (the pipeline's own parameters): for
every blob the depth cue finds on under half of it, whether it lies on a part or bare table,
and the share of its pixels whose colour is one of the depth-read table's colours around it
(the window one part length around, each LAB channel within the colour cues' floors), and its
median height against the table's noise around it. docs/bench/checker-false-parts.md.

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
    colour_share_around,
    outline_step_share,
    pattern_colour_share,
)
from tlessbot_ros.core.localise.cues import height_above_table
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase

sys.path.insert(0, str(Path(__file__).parent))
from outline_step_cues import window  # noqa: E402
from table_false_parts_cues import OFF_PART, ON_PART, segmentations, truth_mask, two_view_frames  # noqa: E402,E501


def palette_share(lab, blob, table, tol):
    """Share of blob pixels whose colour some 1 % of the table pixels share (within tol)."""
    seen = lab[table]
    if len(seen) < 50:
        return float('nan')
    bins = np.floor(seen / (tol / 2)).astype(int)
    keys = {}
    for b in map(tuple, bins):
        keys[b] = keys.get(b, 0) + 1
    need = 0.01 * len(seen)
    px = np.floor(lab[blob] / (tol / 2)).astype(int)
    offs = [(a, b, c) for a in (-2, -1, 0, 1, 2) for b in (-2, -1, 0, 1, 2) for c in (-2, -1, 0, 1, 2)]
    hits = 0
    cache = {}
    for p in map(tuple, px):
        if p not in cache:
            cache[p] = sum(keys.get((p[0] + a, p[1] + b, p[2] + c), 0) for a, b, c in offs) >= need
        hits += cache[p]
    return hits / max(len(px), 1)


def main(argv):
    scenes, templates = argv[:2]
    only = argv[2] if len(argv) > 2 and '=' not in argv[2] else None
    extra = dict(a.split('=') for a in argv[2:] if '=' in a)
    pipeline = None
    print('frame\tview\tlabel\tarea\tdepth_share\tstep\tpalette\th_mm\ttable_mm\tnoise_mm\tz\tcommon\tpattern')
    for images, views, rig in two_view_frames(scenes):
        if pipeline is None:
            kw = {k: type(getattr(SegmentationParams(), k))(v) for k, v in extra.items()}
            pipeline = PerceptionPipeline(rig=rig, templates=TemplateDatabase.load(templates),
                                          segmentation=SegmentationParams(**kw))
        for v, (seg, kw) in segmentations(pipeline, views).items():
            if only and v != only:
                continue
            image, params = images[v], kw['params']
            tol = params.colour_edge_floors * np.array([params.grey_floor, params.lab_floor, params.lab_floor])
            longest = max((e[2] for e in params.whole_parts or ()), default=0.0)
            lab = rgb_to_lab(image.rgb)
            height = height_above_table(image.depth_m, np.asarray(image.intrinsics.K), image.T_world_camera)
            depth = cv2.resize(seg.cues['depth'].view(np.uint8), image.rgb.shape[1::-1],
                               interpolation=cv2.INTER_NEAREST).astype(bool)
            truth = truth_mask(image)
            count, blobs, stats, _ = cv2.connectedComponentsWithStats(seg.foreground.view(np.uint8), connectivity=8)
            for i in range(1, count):
                if stats[i, cv2.CC_STAT_AREA] < params.min_area_px // 2:
                    continue
                near = window(stats[i, :4], OUTLINE_REACH_PX + 4, blobs.shape)
                around = window(stats[i, :4], int(np.ceil(longest)) + 1, blobs.shape)
                blob = blobs[near] == i
                dshare = depth[near][blob].mean()
                if dshare >= 0.5:
                    continue
                on = truth[near][blob].mean()
                label = 'part' if on >= ON_PART else 'table' if on < OFF_PART else 'mixed'
                h = height[around]
                ok = np.isfinite(h) & (blobs[around] == 0)
                tab = h[ok]
                tmed = np.median(tab) if len(tab) else np.nan
                noise = 1.48 * np.median(np.abs(tab - tmed)) if len(tab) else np.nan
                hb = height[near][blob]
                hmed = np.nanmedian(hb) if np.isfinite(hb).any() else np.nan
                pal = palette_share(lab[around], blobs[around] == i, ok, tol)
                print(f'{image.im_id}\t{v}\t{label}\t{stats[i, cv2.CC_STAT_AREA]}\t{dshare:.2f}'
                      f'\t{outline_step_share(lab[near], blob, tol, OUTLINE_REACH_PX):.2f}'
                      f'\t{pal:.2f}\t{1e3 * hmed:.1f}\t{1e3 * tmed:.1f}\t{1e3 * noise:.2f}'
                      f'\t{(hmed - tmed) / noise:.1f}'
                      f'\t{colour_share_around(lab[around], blobs[around] == i, tol):.2f}'
                      f'\t{pattern_colour_share(lab[around], blobs[around] == i, blobs[around] == 0, tol):.2f}',
                      flush=True)
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
