"""The crops of simulated two-view scenes that ``tlessbot train --scenes N`` learns from,
rendered over worker processes.

Every scene is drawn from its own random stream (the simulator's seed and the scene's index),
so scene k is the same whichever process renders it; the crops are put back in scene order, so
the features, and the classifier trained on them, do not depend on the number of workers. A
share of the scenes, spread evenly over their indices
(:func:`~tlessbot_ros.sim.noise.spread_depth_kind`), can have the stereo-like 'smoothed' depth:
the same parts, table and light, another depth model.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from tlessbot_ros.errors import TlessbotError

_CHUNK = 8          # scenes per task handed to a worker
_MAX_WORKERS = 4
_worker: dict = {}  # per worker process: the simulator and the descriptor settings


def default_workers(window_s: float = 0.5) -> int:
    """The worker processes a build uses by default: the cores left idle by the rest of the
    host over ``window_s`` (``/proc/stat``; all the CPUs this process may use where it cannot
    be read), at least 1 and at most 4. On a busy host more processes only add their start
    and contention."""
    import time

    from tlessbot_ros.parallel.spare_cpu import read_cpu_ticks

    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:   # not Linux
        cpus = os.cpu_count() or 1
    before = read_cpu_ticks()
    time.sleep(window_s)
    after = read_cpu_ticks()
    if before is not None and after is not None and sum(after) > sum(before):
        idle = (after[3] + after[4] - before[3] - before[4]) / (sum(after) - sum(before))
        cpus = min(cpus, int(idle * (os.cpu_count() or 1) + 0.5))
    return max(1, min(cpus, _MAX_WORKERS))


def _start(models_dir: str, ids, seed: int, hog, shape, min_pixels: int,
           smoothed_share: float, region_px: int) -> None:
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.noise import DEPTH_KINDS, DepthNoiseParams
    from tlessbot_ros.sim.simulator import SimParams, Simulator

    models = load_models(Path(models_dir), ids)
    simulators = {kind: Simulator(models, params=SimParams(noise=DepthNoiseParams(kind=kind)),
                                  seed=seed) for kind in DEPTH_KINDS}
    _worker.update(simulators=simulators, hog=hog, shape=shape, min_pixels=min_pixels,
                   smoothed_share=smoothed_share, region_px=region_px)


def _describe(indices: list[int]) -> list[tuple[np.ndarray, list[int]]]:
    """Per scene of ``indices``: ((n, D) float32 HOG + shape of its parts in both views, their
    ids)."""
    from tlessbot_ros.core.common import mask_box
    from tlessbot_ros.core.recognise import (
        describe_regions,
        region_points_world,
        shape_features_batch,
    )
    from tlessbot_ros.sim.noise import spread_depth_kind, stereo_region

    hog, shape = _worker['hog'], _worker['shape']
    out = []
    for index in indices:
        kind = spread_depth_kind(index, _worker['smoothed_share'])
        simulator = _worker['simulators'][kind]
        features, labels = [], []
        for view in simulator.frame(index).views.values():
            parts = [g for g in view.gt if g.px_count_visib >= _worker['min_pixels']]
            if not parts:
                continue
            masks = [g.mask_visib for g in parts]
            boxes = [g.bbox_visib for g in parts]
            depth_m = view.depth_mm.astype(np.float32) / 1000.0
            if kind == 'smoothed':   # the part's region as the localiser cuts it
                masks = [stereo_region(m, depth_m, view.intrinsics.K, view.T_world_camera,
                                       grow_px=_worker['region_px']) for m in masks]
                boxes = [mask_box(m) for m in masks]
            points = [region_points_world(depth_m, m, view.intrinsics.K, view.T_world_camera,
                                          box=b) for m, b in zip(masks, boxes)]
            features.append(np.hstack([describe_regions(view.rgb, boxes, masks, params=hog),
                                       shape_features_batch(points, params=shape)]))
            labels += [g.obj_id for g in parts]
        out.append((np.vstack(features).astype(np.float32) if features else None, labels))
    return out


def scene_features(models_dir: Path, hog, shape, *, ids: list[int] | None, scenes: int,
                   seed: int, min_pixels: int = 100, workers: int = 1,
                   smoothed_share: float = 0.0, region_px: int | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Describe every part (>= ``min_pixels`` visible) of ``scenes`` simulated two-view
    frames (simulator seed ``seed``), in both views: ((N, D) float32 HOG + shape, NaN where
    the depth is unusable; (N,) int64 ids), the same for any number of ``workers``
    (processes; 1: this one; 0: :func:`default_workers`). A share ``smoothed_share`` (0-1)
    of the scenes has the 'smoothed' depth kind, the rest the per-pixel one; their parts'
    masks grow by up to ``region_px`` where the depth rises (``stereo_region``; None: the
    turntable's ``smoothed_region_px``)."""
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    from tqdm import tqdm

    chunks = [list(range(k, min(k + _CHUNK, scenes))) for k in range(0, scenes, _CHUNK)]
    workers = workers or default_workers()
    if region_px is None:
        from tlessbot_ros.sim.turntable import TurntableParams

        region_px = TurntableParams.smoothed_region_px
    setup = (str(models_dir), ids, seed, hog, shape, min_pixels, smoothed_share, region_px)
    results: list = []
    with tqdm(total=scenes, desc='scenes', unit='frame') as bar:
        if workers <= 1 or len(chunks) < 2:
            _start(*setup)
            for chunk in chunks:
                results += _describe(chunk)
                bar.update(len(chunk))
        else:
            # spawn: a forked Open3D may hang in its thread pool
            with ProcessPoolExecutor(min(workers, len(chunks)), mp_context=get_context('spawn'),
                                     initializer=_start, initargs=setup) as pool:
                for chunk, described in zip(chunks, pool.map(_describe, chunks)):
                    results += described
                    bar.update(len(chunk))
    features = [f for f, _ in results if f is not None]
    labels = [i for _, ids_ in results for i in ids_]
    if not labels:
        raise TlessbotError('the simulated scenes held no visible parts')
    return np.vstack(features).astype(np.float32), np.asarray(labels, np.int64)
