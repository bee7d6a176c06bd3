"""Paired CPU of the pose stage per frame: this tree against main's ICP kernel, polish on / off.

  PYTHONPATH=. python scripts/polish_cost.py --dataset sim_a [--dataset ...] --main ../main

Each frame is localised and classified once, then ``PerceptionPipeline.estimate_poses`` runs
under four variants, their order rotating from frame to frame (load drift hits all alike),
CPU time (``time.process_time``) of 3 calls each after a warm-up call:

* A: main's ICP kernel (``core/pose/grid_kernels.py`` of the ``--main`` checkout) and every
  finalist polished (``polish_margin_fitness=1``): main's pose stage;
* B: this tree's defaults;
* A0, B0: the same with ``polish_iterations=0`` (no polish).
"""
from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import SIDE, TOP, CameraMount, Rig
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import PoseParams, TemplateDatabase, refinement
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_TEMPLATES
from tlessbot_ros.io.bop import read_split


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--dataset', type=Path, action='append', required=True)
    parser.add_argument('--main', type=Path, required=True, help='a checkout of main')
    args = parser.parse_args(argv)
    spec = importlib.util.spec_from_file_location(
        'main_grid_kernels', args.main / 'tlessbot_ros/core/pose/grid_kernels.py')
    main_kernels = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(main_kernels)
    ours = refinement.gauss_newton
    variants = {'A': (main_kernels.gauss_newton, PoseParams(polish_margin_fitness=1.0)),
                'B': (ours, PoseParams()),
                'A0': (main_kernels.gauss_newton, PoseParams(polish_iterations=0)),
                'B0': (ours, PoseParams(polish_iterations=0))}
    names = list(variants)
    templates = TemplateDatabase.load(DEFAULT_TEMPLATES)
    classifier = LinearClassifier.load(DEFAULT_CLASSIFIER)
    cpu_ms: dict[str, list[float]] = {k: [] for k in names}

    def run(name, views, labels, classes):
        refinement.gauss_newton, pipeline.pose_estimator.params = variants[name]
        pipeline.estimate_poses(views, labels, classes)

    for dataset in args.dataset:
        pipeline = None
        readers = [read_split(dataset, f'test_{v}') for v in (TOP, SIDE)]
        for frame, (top, side) in enumerate(zip(*readers)):
            by_view = {TOP: top, SIDE: side}
            if pipeline is None:
                rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                           for v, im in by_view.items()})
                pipeline = PerceptionPipeline(rig=rig, classifier=classifier,
                                              templates=templates, pose=PoseParams())
            views = {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera)
                     for v, im in by_view.items()}
            fusion = pipeline.localise(views)
            guesses = pipeline.classify({v: views[v].rgb for v in views}, fusion.labels,
                                        views=views)
            classes = {i: g.candidates for i, g in guesses.items()}
            order = names[frame % 4:] + names[:frame % 4]
            for name in order:
                run(name, views, fusion.labels, classes)
            for name in order:
                t0 = time.process_time()
                for _ in range(3):
                    run(name, views, fusion.labels, classes)
                cpu_ms[name].append(1e3 * (time.process_time() - t0) / 3)
    refinement.gauss_newton = ours
    total = {k: float(np.sum(v)) for k, v in cpu_ms.items()}
    frames = len(cpu_ms['A'])
    print(f'{frames} frames; pose stage CPU ms per frame: '
          + ', '.join(f'{k} {total[k] / frames:.1f}' for k in names))
    print(f"B / A {total['B'] / total['A']:.3f}, A / A0 {total['A'] / total['A0']:.3f}, "
          f"B / A0 {total['B'] / total['A0']:.3f}, B0 / A0 {total['B0'] / total['A0']:.3f}, "
          f"(B - A0) / (A - A0) {(total['B'] - total['A0']) / (total['A'] - total['A0']):.3f}")
    return 0


if __name__ == '__main__':
    sys.exit(main())
