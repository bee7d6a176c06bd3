"""Unknown stays unknown by the depth fit: known-part top-1 against false positives per frame.

  PYTHONPATH=. python scripts/unknown_by_fit.py --classifier M.npz --templates T.npz \\
      --renders-known SIM_PARTS --renders-unknown SIM_OTHERS \\
      --real ../shared/data/sygrid_real_d435i --visp ../shared/data --out reports/unknown_fit

The rule is ``FitParams.unknown_below_fitness``: a part whose best template fit explains less
of its depth than the threshold is reported unknown. Each region is fitted once with the rule
off and the shares the rule reads kept (``core.part_fit.explained_share`` of its final pose at
``verify_inlier_m``): on the points inside the fitted model's outline (``unknown_in_outline``,
the default) and on all the region's points (the rule before it); the rule at threshold t is
then exactly "named and share >= t" (it changes nothing else), so one run gives every curve.

The renders (``--renders-known``: ``tlessbot simulate`` of the model's own parts, ground-truth
boxes plus background boxes; ``--renders-unknown``: ``tlessbot simulate`` of other parts, every
box unknown) say which threshold they would choose: the lowest of the grid that names at most
``--max-render-unknown`` of the fitted unknown parts at a cost of at most ``--max-render-cost``
of the known parts' top-1 (or none). The real sets choose nothing; they are measured:

- ``--real``: a real BOP set of the model's parts; the frames with depth: ground-truth boxes
  (known parts) and ``--boxes-per-frame`` background boxes (as ``evaluate --background-boxes``).
- ``--visp``: the real RealSense RGB-D frames of other objects under ``../shared/data``
  (ViSP's RBT sequence and its D435 tutorial frame): the whole pipeline (localiser on the
  depth, classifier, pose stage) runs, and every region named as a part is a false positive.

Writes unknown_fit.md (the tables and the spread of the shares) and unknown_fit.png into --out.
"""
from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from real_unknown import finish_plot  # this script's folder

from tlessbot_ros.tools.support.eval_frames import background_boxes, box_labels

GRID = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9)
NO_FIT = -1.0   # not fitted (too few depth points above the table): unknown_without_fit
DROPPED = -2.0  # no detection: the fragment filter dropped it (its classifier name is scored,
                # as evaluate --oracle boxes does), or the classifier had no candidate


@dataclass
class Record:
    """One region's answer: its set, whether it is a known part (and which), the class the
    pipeline named (0 = unknown), the share the rule reads (inside the fitted outline, as by
    default; NO_FIT: not fitted) and the share of all the region's points
    (``unknown_in_outline`` off), and the share of its points inside the fitted outline."""

    source: str
    frame: int
    truth: int          # the part's id; 0 for background or a part not in the set
    named: int
    fitness: float
    share_all: float = NO_FIT
    covered: float = 1.0
    p50_mm: float = -1.0   # the points inside the outline: median / 90 % distance from the
    p90_mm: float = -1.0   # fitted surface, mm (at most 10; -1: not fitted)
    margin: float = 0.0    # the classifier's margin for the class it named


def make_pipeline(classifier, templates):
    """A fresh pipeline (the table-plane tracker starts anew: a set is another camera), the
    rule off: every region's best fitness is kept."""
    from tlessbot_ros.core.params import FitParams
    from tlessbot_ros.core.pipeline import PerceptionPipeline

    pipeline = PerceptionPipeline(classifier=classifier, templates=templates,
                                  fit_params=FitParams(unknown_below_fitness=0.0,
                                                       unknown_below_cover=0.0))
    pipeline.warm_up()
    pipeline.roi_points = {}
    fit_here = pipeline.fit_part

    def fit_part(job):   # keep each part's ROI cloud: the rule reads its share of it
        pipeline.roi_points[job.detection.instance_id] = job.points
        fit_here(job)
    pipeline.fit_part = fit_part
    return pipeline


def explained(pipeline, detection) -> tuple[float, ...]:
    """What the rule reads of ``detection`` (its final class and pose): the share of its ROI
    cloud explained inside the fitted outline (the default) and of all of it, the share
    inside the outline (:func:`~tlessbot_ros.core.part_fit.outline_shares`) and the median
    and 90 % distance of those points from the fitted surface, mm; NO_FIT: no pose."""
    from dataclasses import replace

    from tlessbot_ros.core.common import transform_points
    from tlessbot_ros.core.part_fit import outline_shares
    from tlessbot_ros.core.pose import inside_outline

    if detection.pose is None:
        return NO_FIT, NO_FIT, 1.0, -1.0, -1.0
    points, estimator = pipeline.roi_points[detection.instance_id], pipeline.pose_estimator
    pose, obj = detection.pose, estimator.database[detection.obj_id]
    inside, covered = outline_shares(pipeline.fit_params, points, detection.obj_id, pose,
                                     estimator)
    every, _ = outline_shares(replace(pipeline.fit_params, unknown_in_outline=False), points,
                              detection.obj_id, pose, estimator)
    model_c = transform_points(pose.T_camera_object, obj.model_points)
    seen = np.asarray(points, np.float64)[inside_outline(points, model_c,
                                                         obj.sample_spacing_m())]
    quantiles = (-1.0, -1.0)
    if len(seen):
        mm = np.minimum(1e3 * estimator.refiner.surface_distances(
            seen, obj, pose.T_camera_object, reach_m=0.01), 10.0)
        quantiles = tuple(float(q) for q in np.quantile(mm, (0.5, 0.9)))
    return inside, every, covered, *quantiles


def fit_boxes(pipeline, image, boxes, truths, source: str, frame: int) -> list[Record]:
    """Classifier, then the pose stage (box mode, as ``evaluate --oracle boxes``) on boxes."""
    from tlessbot_ros.core.pipeline import ViewInput

    if not boxes:
        return []
    view = ViewInput(image.rgb, image.depth_m, image.intrinsics, image.T_world_camera)
    labels = {'side': box_labels(image.rgb.shape[:2], boxes)}
    guesses = pipeline.classify({'side': image.rgb}, labels, views={'side': view})
    pipeline.roi_points.clear()
    detections = pipeline.estimate_poses({'side': view}, labels,
                                         {i: g.candidates for i, g in guesses.items()},
                                         box_mode=True)
    by_instance = {d.instance_id: d for d in detections}
    records = []
    for k, truth in enumerate(truths):
        guess, detection = guesses.get(k + 1), by_instance.get(k + 1)
        named = 0 if guess is None else guess.obj_id
        shares = (DROPPED, DROPPED)
        if detection is not None:
            named = detection.obj_id
            shares = explained(pipeline, detection)
        margin = 0.0 if guess is None else float(guess.margin)
        records.append(Record(source, frame, int(truth), int(named), *shares, margin=margin))
    return records


def bop_records(pipeline, dataset: Path, split: str, source: str, *, known: bool,
                per_frame: int, depth_only: bool = False, seed: int = 0
                ) -> tuple[list[Record], int]:
    """Ground-truth boxes (known parts, or unknown ones with ``known`` False) and background
    boxes of every frame of a BOP split (frames with depth only, if ``depth_only``)."""
    from tqdm import tqdm

    from tlessbot_ros.io.bop import read_split

    rng = np.random.default_rng(seed)
    records, frames = [], 0
    images = list(read_split(dataset, split, load_masks=False))
    for n, image in enumerate(tqdm(images, desc=source, unit='frame')):
        if depth_only and (image.depth_m is None or not np.any(image.depth_m > 0)):
            continue
        frames += 1
        parts = [g for g in image.gt if g.bbox_visib is not None and g.bbox_visib[2] > 0
                 and (g.visib_fract or 0) >= 0.3]
        boxes = [tuple(int(v) for v in g.bbox_visib) for g in parts]
        truths = [g.obj_id if known else 0 for g in parts]
        records += fit_boxes(pipeline, image, boxes, truths, source, n)
        background = background_boxes(rng, boxes, image.rgb.shape[:2], per_frame)
        records += fit_boxes(pipeline, image, background, [0] * len(background),
                             source + ' background', n)
    return records, frames


def visp_frames(root: Path):
    """(rgb, depth_m, K) of the real RealSense RGB-D frames of other objects: ViSP's RBT
    sequence (20 frames) and its D435 tutorial frame (aligned depth)."""
    import cv2

    seq = root / 'visp_images_rbt_sequence' / 'sequence'
    cam = json.loads((seq / 'cam.json').read_text())
    K = np.array([[cam['px'], 0, cam['u0']], [0, cam['py'], cam['v0']], [0, 0, 1]])
    for rgb_path in sorted(seq.glob('color_image_*.png')):
        depth_path = seq / rgb_path.name.replace('color', 'depth').replace('.png', '.npz')
        with np.load(depth_path, allow_pickle=False) as data:
            depth = data['data'].astype(np.float32) * float(cam['depthScale'])
        yield cv2.imread(str(rgb_path))[:, :, ::-1].copy(), depth, K
    d435 = root / 'visp_realsense_tutorial_data' / 'computer-vision' / 'd435_align_depth'
    if d435.is_dir():
        raw = (d435 / 'depth_image_0000.bin').read_bytes()
        height, width = np.frombuffer(raw[:8], '<u4')
        depth = np.frombuffer(raw[8:], '<u2').reshape(height, width).astype(np.float32) * 1e-3
        K = np.array([[605.1467, 0, 325.5325], [0, 604.7915, 244.9508], [0, 0, 1]])
        yield cv2.imread(str(d435 / 'color_image_0000.jpg'))[:, :, ::-1].copy(), depth, K


def visp_records(pipeline, root: Path) -> tuple[list[Record], int]:
    """The whole pipeline (one camera, no extrinsics: the table plane from the depth) on real
    frames without any of the model's parts: every region it keeps is unknown (truth 0)."""
    from tqdm import tqdm

    from tlessbot_ros.core.common import CameraIntrinsics
    from tlessbot_ros.core.pipeline import ViewInput

    records = []
    frames = list(visp_frames(root))
    for n, (rgb, depth, K) in enumerate(tqdm(frames, desc='visp', unit='frame')):
        depth = np.where(depth > 0, depth, np.nan).astype(np.float32)
        pipeline.roi_points.clear()
        intrinsics = CameraIntrinsics(rgb.shape[1], rgb.shape[0], K)
        result = pipeline.process({'side': ViewInput(rgb, depth, intrinsics, None)})
        labelled = set(np.unique(result.labels['side']).tolist()) - {0}
        fitted = {d.instance_id: d for d in result.detections}
        for instance in sorted(labelled):
            d = fitted.get(instance)
            shares = (DROPPED, DROPPED) if d is None else explained(pipeline, d)
            records.append(Record('visp', n, 0, 0 if d is None else int(d.obj_id), *shares,
                                  margin=0.0 if d is None else float(d.class_margin)))
    return records, len(frames)


def kept(records: list[Record], threshold: float, without_fit: bool) -> np.ndarray:
    """Which regions stay named as a part with ``unknown_below_fitness`` at ``threshold``
    (0: off) and ``unknown_without_fit``."""
    named = np.array([r.named != 0 for r in records], bool)
    fitness = np.array([r.fitness for r in records], float)
    if threshold > 0:
        named &= (fitness < 0) | (fitness >= threshold)
    return named & (fitness != NO_FIT) if without_fit else named


def top1(records: list[Record], *rule) -> float:
    """Known parts named right and kept (an unknown answer counts wrong)."""
    right = np.array([r.named == r.truth for r in records], bool)
    return float(np.mean(right & kept(records, *rule))) if records else float('nan')


def named_share(records: list[Record], *rule) -> float:
    return float(np.mean(kept(records, *rule))) if records else float('nan')


def fitted_named_share(records: list[Record], *rule) -> float:
    """:func:`named_share` of the fitted regions alone (those the threshold acts on)."""
    return named_share([r for r in records if r.fitness >= 0], *rule)


def per_frame(records: list[Record], frames: int, *rule) -> float:
    return float(np.sum(kept(records, *rule))) / frames if frames else float('nan')


def curve(sets: dict, without_fit: bool) -> list[dict]:
    """Every threshold's figures with (or without) ``unknown_without_fit``."""
    rows = []
    for t in GRID:
        rule = (t, without_fit)
        rows.append({
            'threshold': t,
            'render_top1': top1(sets['render known'][0], *rule),
            'render_unknown_named': named_share(sets['render unknown'][0], *rule),
            'render_unknown_fitted': fitted_named_share(sets['render unknown'][0], *rule),
            'render_background_fp': per_frame(*sets['render background'], *rule),
            'real_top1': top1(sets['real known'][0], *rule),
            'real_background_fp': per_frame(*sets['real background'], *rule),
            'visp_fp': per_frame(*sets['visp'], *rule)})
    return rows


def choose(rows: list[dict], max_cost: float, max_unknown: float) -> float | None:
    """The threshold the renders alone would choose: the lowest of the grid that names at most
    ``max_unknown`` of the fitted unknown rendered parts (the others it cannot touch), among
    those that cost at most ``max_cost`` of the known renders' top-1 (None when none does)."""
    base = rows[0]['render_top1']
    fits = [r['threshold'] for r in rows if r['render_top1'] >= base - max_cost
            and r['render_unknown_fitted'] <= max_unknown]
    return min(fits) if fits else None


def on_all_points(sets: dict) -> dict:
    """``sets`` with each region's share of all its points as the one the rule reads
    (``unknown_in_outline`` off)."""
    from dataclasses import replace

    return {name: ([replace(r, fitness=r.share_all) for r in records], frames)
            for name, (records, frames) in sets.items()}


def spread(sets: dict) -> list[str]:
    """The shares of the right known fits and of the fitted regions that are no part, on all
    the region's points and inside the fitted outline: min, 10 %, median."""
    groups = (('renders: known parts, right fits', 'render known', True),
              ('real sygrid: known parts, right fits', 'real known', True),
              ('renders: parts of another set', 'render unknown', False),
              ('real ViSP: regions named', 'visp', False))
    lines = ['', 'Shares of the fitted regions (min / 10 % / median):', '',
             '| regions | count | share of all points | share inside the outline |',
             '|---|---|---|---|']
    for label, name, right in groups:
        chosen = [r for r in sets[name][0]
                  if r.fitness >= 0 and (not right or r.named == r.truth)]
        if not chosen:
            continue
        cells = []
        for key in ('share_all', 'fitness'):
            x = np.array([getattr(r, key) for r in chosen])
            cells.append(f'{x.min():.2f} / {np.quantile(x, 0.1):.2f} / {np.median(x):.2f}')
        lines.append(f'| {label} | {len(chosen)} | {cells[0]} | {cells[1]} |')
    return lines


def collect(args) -> dict[str, tuple[list[Record], int]]:
    """(records, frames) of every set, each with a fresh pipeline."""
    from tlessbot_ros.core.pose import TemplateDatabase
    from tlessbot_ros.core.recognise import LinearClassifier

    classifier = LinearClassifier.load(args.classifier)
    templates = TemplateDatabase.load(args.templates)

    def split(records, frames, source):
        return {source: ([r for r in records if r.source == source], frames),
                f'{source.split()[0]} background':
                    ([r for r in records if r.source.endswith('background')], frames)}

    sets = {}
    n = args.boxes_per_frame
    sets.update(split(*bop_records(make_pipeline(classifier, templates), args.renders_known,
                                   'test_side', 'render known', known=True, per_frame=n),
                      'render known'))
    records, frames = bop_records(make_pipeline(classifier, templates), args.renders_unknown,
                                  'test_side', 'render unknown', known=False, per_frame=0)
    sets['render unknown'] = (records, frames)
    sets.update(split(*bop_records(make_pipeline(classifier, templates), args.real, 'test',
                                   'real known', known=True, per_frame=n, depth_only=True),
                      'real known'))
    sets['visp'] = visp_records(make_pipeline(classifier, templates), args.visp)
    return sets


def residuals(sets: dict) -> list[str]:
    """Per part, the right fits on the real set and on the renders: how much of the region
    lies inside the outline, and how far those points lie from the fitted surface."""
    lines = ['', 'Right fits per part (real sygrid | renders): share of the region inside the '
             'outline (min-max), median over the fits of their median and 90 % distance from '
             'the fitted surface inside the outline, mm (capped at 10):', '',
             '| part | fits real / renders | inside the outline | median distance | '
             '90 % distance |', '|---|---|---|---|---|']
    right = {name: [r for r in sets[name][0] if r.fitness >= 0 and r.named == r.truth]
             for name in ('real known', 'render known')}
    for part in sorted({r.truth for r in right['real known']}):
        cells = [[r for r in right[name] if r.truth == part] for name in right]
        line = f'| {part} | {len(cells[0])} / {len(cells[1])} |'
        for key in ('covered', 'p50_mm', 'p90_mm'):
            texts = []
            for fits in cells:
                x = np.array([getattr(r, key) for r in fits])
                texts.append('-' if not len(x) else f'{x.min():.2f}-{x.max():.2f}'
                             if key == 'covered' else f'{np.median(x):.1f}')
            line += f' {texts[0]} \\| {texts[1]} |'
        lines.append(line)
    return lines


def margins(sets: dict, default: float, cover: float = 0.5) -> list[str]:
    """Would the classifier's margin, as a second test chosen on the renders (a low quantile
    of the right rendered fits' margins), separate what the default rule still names?"""
    def right(name):
        return np.array([r.margin for r in sets[name][0] if r.fitness >= 0
                         and r.named == r.truth])
    rendered, real = right('render known'), right('real known')
    visp = [r for r in sets['visp'][0] if r.fitness >= 0 and r.named != 0
            and r.fitness >= default and r.covered >= cover]
    named = np.array([r.margin for r in visp])
    if not len(rendered) or not len(real) or not len(named):
        return []
    lines = ['', "The classifier's margin of the right fits (renders, real sygrid) and of the "
             f'fitted ViSP regions the default rule still names ({len(named)}): min / median '
             f'{rendered.min():.0f} / {np.median(rendered):.0f}, {real.min():.0f} / '
             f'{np.median(real):.0f}, {named.min():.0f} / {np.median(named):.0f}.', '',
             '| unknown below margin (quantile of the right rendered fits) | real sygrid: right '
             'fits kept | ViSP: fitted regions still named |', '|---|---|---|']
    for q in (0.01, 0.02, 0.05):
        t = float(np.quantile(rendered, q))
        lines.append(f'| {t:.0f} ({q:.0%}) | {np.sum(real >= t)} / {len(real)} | '
                     f'{np.sum(named >= t)} / {len(named)} |')
    return lines


def cover_table(sets: dict, default: float) -> list[str]:
    """ViSP's false positives per frame (the whole pipeline: the regions are the localiser's
    masks) at the default threshold and each ``unknown_below_cover``; the box sets do not
    read the cover."""
    records, frames = sets['visp']
    lines = ['', f'Masks only (ViSP, whole pipeline), at the default {default:.1f} inside the '
             'outline and `unknown_below_cover` (a fit whose outline covers less than that '
             "share of its mask's points is unknown):", '',
             '| unknown below cover | real ViSP RGB-D: FP/frame |', '|---|---|']
    for cover in (0.0, 0.3, 0.5, 0.7):
        kept_now = kept(records, default, False) & np.array(
            [r.fitness < 0 or r.covered >= cover for r in records], bool)
        lines.append(f'| {cover:.1f} | {np.sum(kept_now) / frames:.2f} |')
    return lines


def table(rows: list[dict], marks: dict[float, str], title: str) -> list[str]:
    """One Markdown table of every threshold's figures; ``marks``: {threshold: note}."""
    lines = [
        '', title, '',
        '| unknown below fitness | renders: known top-1 | renders: unknown parts named (of '
        'the fitted) | renders: background FP/frame | real sygrid (depth): known top-1 | '
        'real sygrid: background FP/frame | real ViSP RGB-D: FP/frame |',
        '|---|---|---|---|---|---|---|']
    for r in rows:
        mark = marks.get(r['threshold'], ' (off)' if r['threshold'] == 0 else '')
        lines.append(f"| {r['threshold']:.1f}{mark} | {r['render_top1']:.3f} | "
                     f"{r['render_unknown_named']:.3f} ({r['render_unknown_fitted']:.3f}) | "
                     f"{r['render_background_fp']:.2f} | "
                     f"{r['real_top1']:.3f} | {r['real_background_fp']:.2f} | "
                     f"{r['visp_fp']:.2f} |")
    return lines


def plot(rows: list[dict], every: list[dict], default: float, path: Path) -> None:
    """Left: known-part top-1 by threshold; right: top-1 against false positives per frame;
    the share inside the fitted outline (solid, the rule's) and of all the region's points
    (dashed, ``every``); the default starred."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    t = [r['threshold'] for r in rows]
    styles = ((rows, '-', 'inside the outline'), (every, '--', 'all points'))
    for series, style, suffix in styles:
        for (key, label), colour in zip((('render_top1', 'renders: known top-1'),
                                         ('real_top1', 'real sygrid: known top-1'),
                                         ('render_unknown_fitted',
                                          'renders: fitted unknown parts named')),
                                        ('C0', 'C1', 'C2')):
            left.plot(t, [r[key] for r in series], 'o' + style, color=colour, ms=4,
                      label=f'{label} ({suffix})')
    left.axvline(default, color='grey', ls=':', label='default')
    left.set_xlabel('unknown_below_fitness')
    curves = (('real_background_fp', 'real_top1', 'real sygrid, background boxes'),
              ('visp_fp', 'real_top1', 'real ViSP RGB-D frames, whole pipeline'),
              ('render_background_fp', 'render_top1', 'renders, background boxes'))
    for (fp, top, label), colour in zip(curves, ('C0', 'C1', 'C2')):
        for series, style, suffix in styles:
            right.plot([r[fp] for r in series], [r[top] for r in series], 'o' + style,
                       color=colour, label=f'{label} ({suffix})', ms=4)
        star = next(r for r in rows if r['threshold'] == default)
        right.plot(star[fp], star[top], 'k*', ms=11)
    right.set_xlabel('false positives per frame (regions that are no part, named)')
    right.set_ylabel('known-part top-1 (real sygrid; renders for renders)')
    finish_plot(fig, (left, right), path, top=1.02, legend_size=6)


def report(sets: dict, args) -> tuple[list[str], list[dict], list[dict]]:
    """The Markdown lines, and the curves inside the outline and on all points."""
    from tlessbot_ros.core.params import FitParams

    default = FitParams().unknown_below_fitness
    rows, every = curve(sets, without_fit=False), curve(on_all_points(sets), without_fit=False)
    lines = ['Counts (regions / frames): ' + '; '.join(
        f'{k} {len(r)} / {f}' for k, (r, f) in sets.items())]
    for name, series in (('the share inside the fitted outline (the default)', rows),
                         ("the share of all the region's points", every)):
        chosen = choose(series, args.max_render_cost, args.max_render_unknown)
        lines += ['', f'Renders alone, on {name}: ' + (
            'no threshold of the grid' if chosen is None else f'**{chosen:.1f}**') +
            f' names at most {args.max_render_unknown:.0%} of the fitted unknown rendered '
            f'parts at a cost of at most {args.max_render_cost:.2f} of their known top-1.']
    marks = {default: ' (default)'}
    lines += table(rows, marks, 'The share inside the fitted outline (`unknown_in_outline: '
                   'true`, the default); a part that is not fitted keeps its name:')
    lines += table(every, {}, "The share of all the region's points (`unknown_in_outline: "
                   'false`):')
    lines += table(curve(sets, without_fit=True), marks, 'Inside the outline, with '
                   '`unknown_without_fit: true` (a region with too few depth points is unknown '
                   'too):')
    return (lines + spread(sets) + residuals(sets) + cover_table(sets, default)
            + margins(sets, default), rows, every)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--classifier', type=Path)
    parser.add_argument('--templates', type=Path)
    parser.add_argument('--renders-known', type=Path,
                        help='tlessbot simulate --models <the parts> --cameras side')
    parser.add_argument('--renders-unknown', type=Path,
                        help='tlessbot simulate --models <other parts> --cameras side')
    parser.add_argument('--real', type=Path, help='real BOP set of the parts')
    parser.add_argument('--visp', type=Path,
                        help='folder holding visp_images_rbt_sequence (../shared/data)')
    parser.add_argument('--boxes-per-frame', type=int, default=20)
    parser.add_argument('--max-render-cost', type=float, default=0.02,
                        help='top-1 a threshold may cost on the known renders')
    parser.add_argument('--max-render-unknown', type=float, default=0.05,
                        help='share of the unknown rendered parts it may still name')
    parser.add_argument('--out', type=Path, default=Path('reports/unknown_fit'))
    parser.add_argument('--records', type=Path,
                        help='tabulate the records.json of an earlier run (no fitting)')
    args = parser.parse_args(argv)
    if args.records:
        sets = {name: ([Record(**r) for r in v['regions']], v['frames'])
                for name, v in json.loads(args.records.read_text()).items()}
    elif None in (args.classifier, args.templates, args.renders_known, args.renders_unknown,
                  args.real, args.visp):
        parser.error('give --records, or every one of --classifier --templates '
                     '--renders-known --renders-unknown --real --visp')
    else:
        sets = collect(args)
    lines, rows, every = report(sets, args)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / 'unknown_fit.md').write_text('\n'.join(lines) + '\n', encoding='utf-8')
    (args.out / 'records.json').write_text(json.dumps(
        {name: {'frames': f, 'regions': [vars(r) for r in recs]}
         for name, (recs, f) in sets.items()}), encoding='utf-8')
    from tlessbot_ros.core.params import FitParams
    plot(rows, every, FitParams().unknown_below_fitness, args.out / 'unknown_fit.png')
    print('\n'.join(lines))
    return 0


if __name__ == '__main__':
    sys.exit(main())
