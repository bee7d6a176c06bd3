"""Rig refinement in the localiser: its cost per frame against the localiser's own work.

    tlessbot bench rig-refinement --bag BAG [--config config/cell.yaml] [--truth RIG.yaml]

Runs a bag's frames, in order, through what the localiser does per frame (no ROS): the rig
refinement (``rig_refinement.*``: observe the frame's tables and parts, solve when due) and
the segmentation and fusion (``PerceptionPipeline.localise``), and times both in the same
process. Prints per frame the two times (the table planes the refinement is handed are the
pipeline's, found as without it, and count as the localiser's own work), whether the
refinement solved, its state and the rig the fusion used, then the mean refinement time as a
share of the localiser's own, over the first frames (while it solves each frame) and after.
Frame 0 is left out of the means: it pays the first calls, which the node's warm-up takes.
With --truth (the bag's true rig), the errors of the rig in use (gauge-free) are printed as
they change.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--bag', required=True, help='bag with /top and /side colour and depth')
    parser.add_argument('--config', type=Path, default=None,
                        help='cell YAML the localiser is given (default config/cell.yaml)')
    parser.add_argument('--truth', type=Path, default=None, help="cell YAML with the bag's rig")
    parser.add_argument('--mode', default='use', choices=('use', 'report'),
                        help='rig_refinement.mode (default use)')
    parser.add_argument('--passes', type=int, default=1, help='passes over the bag (default 1)')


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from tlessbot_ros.core.calibrate import rig_errors
    from tlessbot_ros.core.calibrate.refinement import (
        RigRefinementParams,
        RigRefiner,
        refined_pipeline,
    )
    from tlessbot_ros.core.common import CameraMount, Rig
    from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
    from tlessbot_ros.tools.support.calibration import bag_frames
    from tlessbot_ros.tools.support.rig import load_rig

    configured = load_rig(args.config)
    truth = load_rig(args.truth) if args.truth else None
    frames = list(bag_frames(args.bag, colour=True))
    refiner = None
    rows, refine_ms, localise_ms = [], [], []
    used = None
    for _ in range(max(1, args.passes)):
        for frame in frames:
            views = {c: ViewInput(rgb=frame.rgb[c], depth_m=frame.depth[c],
                                  intrinsics=configured[c].intrinsics) for c in frame.depth}
            for c, view in views.items():   # the bag's own camera matrices
                view.intrinsics = type(view.intrinsics)(
                    width=view.rgb.shape[1], height=view.rgb.shape[0], K=frame.K[c])
            prior = Rig(cameras={c: CameraMount(c, views[c].intrinsics,
                                                configured[c].T_world_camera) for c in views})
            refiner = refiner or RigRefiner(prior, RigRefinementParams(mode=args.mode))

            def make(rig: Rig, views: dict = views) -> PerceptionPipeline:
                for name, view in views.items():
                    view.T_world_camera = rig[name].T_world_camera
                return PerceptionPipeline(rig=rig)

            solves, spent = refiner.solves, refiner.total_ms
            t0 = time.perf_counter()
            pipeline = refined_pipeline(refiner, views, make)
            pipeline.localise(views)
            t2 = time.perf_counter()
            # the refiner's own time; the table planes it is handed are the pipeline's, found
            # for its table frames as without refinement (counted with the localiser's work)
            refine_ms.append(refiner.total_ms - spent)
            localise_ms.append(1e3 * (t2 - t0) - refine_ms[-1])
            status = refiner.status().values
            line = (f'| {len(rows)} | {refine_ms[-1]:.1f} | {localise_ms[-1]:.1f} | '
                    f'{"yes" if refiner.solves > solves else ""} | {status.get("rig_state")} | '
                    f'{refiner.in_use} |')
            if truth is not None and refiner.rig is not used:
                errors = rig_errors(truth, refiner.rig)
                line += (f' {errors.relative.angle_deg:.2f} deg / '
                         f'{1e3 * errors.relative.offset_m:.1f} mm |')
            else:
                line += ' |'
            used = refiner.rig
            rows.append(line)
    first = 2 * RigRefinementParams().scene.min_frames + 1
    refine, localise = np.asarray(refine_ms), np.asarray(localise_ms)
    print('| frame | refinement ms | planes + segmentation + fusion ms | solved | state | '
          'rig used | rig in use vs truth (top -> side) |')
    print('|---|---|---|---|---|---|---|')
    print('\n'.join(rows))
    print()
    # frame 0 pays both parts' first calls (imports, allocations), which the node's warm-up
    # takes before it reports ready
    for label, part in ((f'frames 1-{first - 1}', slice(1, first)),
                        (f'frames {first}-', slice(first, None)),
                        ('frames 1-', slice(1, None))):
        r, s = refine[part], localise[part]
        if len(r):
            print(f'{label}: refinement {r.mean():.1f} ms per frame (median '
                  f"{np.median(r):.1f}), the localiser's own work {s.mean():.1f} ms "
                  f'(median {np.median(s):.1f}): ratio of the means {r.mean() / s.mean():.3f}')
    if refiner is not None and refiner.estimate is not None:
        print(f'estimate: {refiner.estimate.summary()}; {refiner.solves} solves')
    return 0
