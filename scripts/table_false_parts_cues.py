"""Which cue tells the top view's false flat parts on smoothed depth from true thin parts:
for every blob of the top view's foreground (before instance separation; the pipeline's own
parameters, with the colour edge test off), whether it lies on a ground-truth part (its top
visible mask) or on bare table, and the values of the candidate cues.
docs/bench/table-false-parts.md.

    python scripts/table_false_parts_cues.py SCENES TEMPLATES [FRAMES]

Cues per blob: its share of depth candidates; the colour step across its outline (the
largest LAB channel step between the medians of a band inside and a band outside it, over
that channel's cut-off floor) against the whole band outside; the share of the band inside
that has the colour of the band outside where the depth reads table, within one floor
(``colour_edge.table_colour_share``: 0 when that is under half the band);
the length of the region of its colour (``colour_edge.colour_region_length``, within one
floor) over the longest a part can look in the view; the height step across the outline
(median height inside less the band outside, mm).
"""
from __future__ import annotations

import sys
from collections.abc import Callable, Iterator

import cv2
import numpy as np

import tlessbot_ros.core.pipeline as pipeline_module
from tlessbot_ros.core.common import CameraMount, Rig
from tlessbot_ros.core.localise import SegmentationParams
from tlessbot_ros.core.localise.colour import rgb_to_lab
from tlessbot_ros.core.localise.colour_edge import (
    colour_region_length,
    rings,
    table_colour_share,
)
from tlessbot_ros.core.localise.cues import height_above_table, view_depth_cue
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.io.bop import read_split

RING_PX = SegmentationParams().colour_edge_ring_px
ON_PART = 0.3    # share of an instance on a ground-truth mask: a true part
OFF_PART = 0.05  # below: bare table


def instance_cues(mask: np.ndarray, others: np.ndarray, lab: np.ndarray, height: np.ndarray,
                  depth_candidate: np.ndarray, depth_table: np.ndarray, floors: np.ndarray,
                  longest_px: float) -> dict[str, float]:
    """The cue values of one blob (full-resolution masks and images)."""
    inner, outer = rings(mask, others, RING_PX)
    if inner.sum() < 5 or outer.sum() < 5:
        return {}
    step = np.median(lab[inner], axis=0) - np.median(lab[outer], axis=0)
    share, colour = table_colour_share(lab, mask, others, depth_table, RING_PX, floors)
    h_in, h_out = height[mask], height[outer]
    h_in, h_out = h_in[~np.isnan(h_in)], h_out[~np.isnan(h_out)]
    return {'area': float(mask.sum()), 'depth_share': float(depth_candidate[mask].mean()),
            'step_over_floor': float(np.max(np.abs(step) / floors)),
            'table_colour_share': share,
            'region_over_longest': colour_region_length(lab, mask, colour, floors) / longest_px,
            'height_step_mm': float(1000 * (np.median(h_in) - np.median(h_out)))
            if h_in.size and h_out.size else float('nan')}


def segmentations(pipeline: PerceptionPipeline, views: dict) -> dict:
    """{view: (Segmentation, segment's keyword arguments)} as ``pipeline`` localises the frame
    ``views`` ({view: ViewInput})."""
    seen: dict = {}
    original: Callable = pipeline_module.segment

    def spy(rgb, **kw):
        out = original(rgb, **kw)
        seen[next(v for v in views if views[v].rgb is rgb)] = (out, kw)
        return out
    pipeline_module.segment = spy
    try:
        pipeline.localise(views)
    finally:
        pipeline_module.segment = original
    return seen


def two_view_frames(scenes: str, *, load_masks: bool = True) -> Iterator[tuple[dict, dict, Rig]]:
    """({view: dataset image}, {view: ViewInput}, the rig of the first frame) of each frame of
    a two-view scenes folder (test_top + test_side)."""
    rig = None
    for top, side in zip(read_split(scenes, 'test_top', load_masks=load_masks),
                         read_split(scenes, 'test_side', load_masks=load_masks)):
        images = {'top': top, 'side': side}
        if rig is None:
            rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                       for v, im in images.items()})
        yield images, {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera)
                       for v, im in images.items()}, rig


def truth_mask(image) -> np.ndarray:
    """(H, W) bool: the union of a dataset image's ground-truth visible masks."""
    truth = np.zeros(image.rgb.shape[:2], bool)
    for gt in image.gt:
        if gt.mask is not None:
            truth |= gt.mask
    return truth


def main(argv: list[str]) -> int:
    scenes, templates = argv[:2]
    frames = {int(a) for a in argv[2].split(',')} if len(argv) > 2 else None
    pipeline = None
    print('frame\tlabel\tarea\tdepth_share\tstep_over_floor\ttable_colour_share'
          '\tregion_over_longest\theight_step_mm')
    for images, views, rig in two_view_frames(scenes):
        top = images['top']
        if frames is not None and top.im_id not in frames:
            continue
        if pipeline is None:
            pipeline = PerceptionPipeline(
                rig=rig, templates=TemplateDatabase.load(templates),
                segmentation=SegmentationParams(colour_edge_floors=0.0))
        seg, kw = segmentations(pipeline, views)['top']
        params, T = kw['params'], kw['T_world_camera']
        floors = np.array([params.grey_floor, params.lab_floor, params.lab_floor])
        lab = rgb_to_lab(top.rgb)
        height = height_above_table(top.depth_m, top.intrinsics.K, T)
        depth_cand = cv2.resize(seg.cues['depth'].view(np.uint8), top.rgb.shape[1::-1],
                                interpolation=cv2.INTER_NEAREST).astype(bool)
        cue = view_depth_cue(top.depth_m, top.intrinsics, T, top.rgb.shape,
                             seg.cues['depth'].shape, params, with_surfaces=False)
        depth_table = cv2.resize(cue.table.view(np.uint8), top.rgb.shape[1::-1],
                                 interpolation=cv2.INTER_NEAREST).astype(bool)
        truth = truth_mask(top)
        count, blobs = cv2.connectedComponents(seg.foreground.view(np.uint8), connectivity=8)
        for i in range(1, count):
            mask = blobs == i
            on = truth[mask].mean()
            label = 'true' if on >= ON_PART else 'false' if on < OFF_PART else 'mixed'
            cues = instance_cues(mask, seg.foreground & ~mask, lab, height, depth_cand,
                                 depth_table, floors, seg.longest_part_px)
            if cues:
                print(f'{top.im_id}\t{label}\t' + '\t'.join(f'{v:.3g}' for v in cues.values()))
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
