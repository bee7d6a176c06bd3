"""Recognition by fit where the classifier is unsure: top-1 and time per part, against the
classifier alone and today's verification, in the same run.

On every frame of a BOP dataset (simulated: ``tlessbot simulate --out``; real: any BOP split
with depth) the ground-truth boxes are the regions (as ``evaluate --oracle boxes``); each part
is named three ways:

- ``classifier``: the classifier alone (its scores summed over the views);
- ``verify``: today's pose stage, the classifier's best ``class_candidates`` verified by fit;
- ``fit``: with ``fit_rank_below_margin`` (core/by_fit.py): where the margin is low, up to
  ``fit_rank_max_candidates`` parts ranked by their template fit.

Times per part: the classifier's frame time over its parts, and each part's own fit (all its
candidates), as p50 / p95 over the parts. Frames without depth are skipped (no fit).

    tlessbot bench fit-ranking --dataset /tmp/sim --below-margin 1.0 --out reports/fit-ranking
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tlessbot_ros.core.params import ClassifyParams, FitParams

MIN_VISIB = 0.3   # the targets of evaluate


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--dataset', type=Path, required=True, help='BOP dataset root')
    parser.add_argument('--split', help='one split (default: test_top + test_side when both '
                                        'exist, else test)')
    parser.add_argument('--classifier', type=Path, help='model .npz (default: packaged)')
    parser.add_argument('--templates', type=Path, help='template .npz (default: packaged)')
    parser.add_argument('--below-margin', type=float, default=1.0,
                        help='fit_rank_below_margin of the fit variant (default 1.0)')
    parser.add_argument('--max-candidates', type=int,
                        default=ClassifyParams.fit_rank_max_candidates,
                        help='fit_rank_max_candidates (0 = all parts; default '
                             f'{ClassifyParams.fit_rank_max_candidates})')
    parser.add_argument('--min-fitness', type=float, default=FitParams.fit_rank_min_fitness,
                        help='fit_rank_min_fitness: unknown below (default 0 = off)')
    parser.add_argument('--coverage-weight', type=float,
                        default=FitParams.fit_rank_coverage_weight,
                        help='fit_rank_coverage_weight (default: the pipeline default; 0 = off)')
    parser.add_argument('--limit', type=int, help='at most N frames')
    parser.add_argument('--out', type=Path, default=Path('reports/fit-ranking'))


class _TimedFitter:
    """A :class:`~tlessbot_ros.core.pipeline.PartFitter` that fits here and times each part."""

    def __init__(self) -> None:
        self.seconds: list[float] = []
        self.candidates: list[int] = []

    def fit_all(self, jobs, fit_here, fitted) -> None:
        for job in jobs:
            t0 = time.perf_counter()
            fit_here(job)
            self.seconds.append(time.perf_counter() - t0)
            self.candidates.append(len(job.candidates))
            fitted(job)


def _frames(dataset: Path, split: str | None, limit: int | None):
    """Per frame, {view: BopImage} (both camera splits of a simulated dataset, else one)."""
    from tlessbot_ros.core.common import SIDE, TOP
    from tlessbot_ros.io.bop import list_splits, read_split

    splits = list_splits(dataset)
    if split is None and {'test_top', 'test_side'} <= set(splits):
        readers = {TOP: read_split(dataset, 'test_top', limit=limit),
                   SIDE: read_split(dataset, 'test_side', limit=limit)}
    else:
        readers = {SIDE: read_split(dataset, split or 'test', limit=limit)}
    for images in zip(*readers.values()):
        yield dict(zip(readers, images))


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from tlessbot_ros.core.common import SIDE
    from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
    from tlessbot_ros.core.pose import TemplateDatabase
    from tlessbot_ros.core.recognise import load_classifier
    from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_TEMPLATES
    from tlessbot_ros.tools.support.eval_frames import oracle_labels

    base = PerceptionPipeline(classifier=load_classifier(args.classifier or DEFAULT_CLASSIFIER),
                              templates=TemplateDatabase.load(args.templates or DEFAULT_TEMPLATES))
    base.warm_up()
    fit = base.replace(classify_params=replace(
        base.classify_params, fit_rank_below_margin=args.below_margin,
        fit_rank_max_candidates=args.max_candidates), fit_params=replace(
        base.fit_params, fit_rank_min_fitness=args.min_fitness,
        fit_rank_coverage_weight=args.coverage_weight))
    fitters = {'verify': _TimedFitter(), 'fit': _TimedFitter()}
    truth, named = [], {'classifier': [], 'verify': [], 'fit': []}
    classify_ms, ranked_parts, skipped = [], [], 0
    for by_view in tqdm(list(_frames(args.dataset, args.split, args.limit)), desc='frames'):
        if any(im.depth_m is None for im in by_view.values()):
            skipped += 1
            continue
        views = {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera)
                 for v, im in by_view.items()}
        labels = oracle_labels(by_view)
        rgb = {v: im.rgb for v, im in by_view.items()}
        targets = {k + 1: gt.obj_id for k, gt in enumerate(by_view[SIDE].gt)
                   if (gt.visib_fract or 0) >= MIN_VISIB}
        if not truth:   # the classifier's first call compiles and loads: not timed
            base.classify(rgb, labels, views=views)
        for name, pipeline in (('verify', base), ('fit', fit)):
            t0 = time.perf_counter()
            guesses = pipeline.classify(rgb, labels, views=views)
            if name == 'verify':
                classify_ms.append(1e3 * (time.perf_counter() - t0) / max(len(guesses), 1))
            detections = pipeline.estimate_poses(
                views, labels, {i: g.candidates for i, g in guesses.items()}, box_mode=True,
                fitter=fitters[name])
            by_instance = {i: g.obj_id for i, g in guesses.items()}
            if name == 'verify':
                named['classifier'] += [by_instance.get(i, 0) for i in targets]
            by_instance.update({d.instance_id: d.obj_id for d in detections})
            named[name] += [by_instance.get(i, 0) for i in targets]
            if name == 'fit':
                ranked_parts += [len(guesses[i].candidates) > base.classify_params.class_candidates
                                 if i in guesses else False for i in targets]
        truth += list(targets.values())
    report = _report(np.asarray(truth), {k: np.asarray(v) for k, v in named.items()},
                     classify_ms, fitters, np.asarray(ranked_parts, bool), skipped, args)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / 'fit-ranking.md').write_text(report['markdown'] + '\n', encoding='utf-8')
    (args.out / 'fit-ranking.json').write_text(json.dumps(
        {k: v for k, v in report.items() if k != 'markdown'}, indent=1), encoding='utf-8')
    print(report['markdown'])
    print(f'-> {args.out / "fit-ranking.md"}')
    return 0


def _percentiles(values) -> tuple[float, float]:
    values = np.asarray(values, float)
    return (float(np.percentile(values, 50)), float(np.percentile(values, 95))) \
        if values.size else (float('nan'), float('nan'))


def _report(truth, named, classify_ms, fitters, ranked, skipped, args) -> dict:
    """Markdown table and figures: top-1, parts, candidates and ms per part of each variant."""
    rows, figures = [], {}
    for name in ('classifier', 'verify', 'fit'):
        right = named[name] == truth
        if name == 'classifier':
            p50, p95 = _percentiles(classify_ms)
            fits = 0.0
        else:
            p50, p95 = _percentiles(1e3 * np.asarray(fitters[name].seconds))
            fits = float(np.mean(fitters[name].candidates)) if fitters[name].candidates else 0
        figures[name] = {'top1': float(right.mean()) if truth.size else None,
                         'ms_p50': p50, 'ms_p95': p95, 'candidates_mean': fits,
                         'top1_on_ranked': float(right[ranked].mean()) if ranked.any() else None,
                         'unknown': int(np.sum(named[name] == 0))}
        rows.append(f'| {name} | {right.mean():.3f} | '
                    + (f'{right[ranked].mean():.3f}' if ranked.any() else '-')
                    + f' | {figures[name]["unknown"]} | {fits:.2f} | {p50:.2f} | {p95:.2f} |')
    fit_ms = 1e3 * np.asarray(fitters['fit'].seconds)
    many = np.asarray(fitters['fit'].candidates) > ClassifyParams().class_candidates
    ranked_ms = fit_ms[many] if fit_ms.size else fit_ms
    p50, p95 = _percentiles(ranked_ms)
    head = (f'{args.dataset} ({truth.size} parts at visib >= {MIN_VISIB}, {skipped} frames '
            f'without depth skipped); fit: fit_rank_below_margin {args.below_margin}, '
            f'fit_rank_max_candidates {args.max_candidates}, fit_rank_min_fitness '
            f'{args.min_fitness}, fit_rank_coverage_weight {args.coverage_weight}; '
            f'{int(ranked.sum())} parts ranked by fit '
            f'(their own fit: p50 {p50:.2f} ms, p95 {p95:.2f} ms)')
    table = '\n'.join([head, '', '| variant | top-1 | top-1 on the ranked parts | unknown | '
                       'candidates per part | ms/part p50 | ms/part p95 |',
                       '|---|---:|---:|---:|---:|---:|---:|', *rows])
    return {'markdown': table, 'parts': int(truth.size), 'ranked_parts': int(ranked.sum()),
            'skipped_frames': skipped, 'ranked_fit_ms_p50': p50, 'ranked_fit_ms_p95': p95,
            'variants': figures}
