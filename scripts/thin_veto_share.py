"""Per part, the share of its pixels that the depth's veto calls table (the colour cues are
dropped there) and the share the depth cue finds, in one view of a set of scenes: the inner
pixels of each visible mask (eroded one cue pixel), at the cue scale, with the view's own
segmentation parameters. docs/bench/smoothed-parts-missed.md.

    python scripts/thin_veto_share.py SCENES TEMPLATES [VIEW]
"""
from __future__ import annotations

import sys
from collections import defaultdict
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core.common import SIDE, TOP, CameraMount, Rig
from tlessbot_ros.core.localise.cues import downscale, view_depth_cue
from tlessbot_ros.core.localise.part_scale import view_segmentation
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.io.bop import read_split


def main(argv: list[str]) -> int:
    scenes, templates = Path(argv[0]), Path(argv[1])
    view = argv[2] if len(argv) > 2 else SIDE
    database = TemplateDatabase.load(templates)
    pipeline = None
    shares: dict[int, list[tuple[float, float]]] = defaultdict(list)
    sigmas = []
    for top, side in zip(*(read_split(scenes, f'test_{v}') for v in (TOP, SIDE))):
        by_view = {TOP: top, SIDE: side}
        if pipeline is None:
            rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                       for v, im in by_view.items()})
            pipeline = PerceptionPipeline(rig=rig, templates=database)
        im = by_view[view]
        frame = pipeline.table_frame(view, ViewInput(im.rgb, im.depth_m, im.intrinsics,
                                                     im.T_world_camera))
        params = view_segmentation(pipeline.segmentation, pipeline.part_extents_m,
                                   im.intrinsics.K, frame.T_world_camera)
        small = downscale(im.rgb, params.cue_scale)
        cue = view_depth_cue(im.depth_m, im.intrinsics, frame.T_world_camera, im.rgb.shape,
                             small.shape, params)
        sigmas.append(cue.sigma_m)
        for part in im.gt:
            if part.mask is None or part.mask.sum() < 100:
                continue
            mask = cv2.resize(part.mask.view(np.uint8), (small.shape[1], small.shape[0]),
                              interpolation=cv2.INTER_NEAREST)
            inner = cv2.erode(mask, np.ones((3, 3), np.uint8)) > 0
            if inner.sum() >= 10:
                shares[part.obj_id].append((cue.table[inner].mean(), cue.candidate[inner].mean()))
    print(f'{scenes} {view}: table noise (median over frames) {1000 * np.median(sigmas):.2f} mm')
    for obj_id in sorted(shares):
        a = np.array(shares[obj_id])
        print(f'obj {obj_id}: {len(a)} masks, veto share {a[:, 0].mean():.2f} (over 0.3: '
              f'{np.sum(a[:, 0] > 0.3)}), depth cue share {a[:, 1].mean():.2f}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
