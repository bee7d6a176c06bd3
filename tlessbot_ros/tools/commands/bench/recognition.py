"""Recognition accuracy per object (paper Table 1), confusion matrix and per-crop timing.

Test crops are cut by the ground-truth visible masks from simulated two-view table scenes
(``Simulator(models, seed=--seed)``: other seeds, tables, lights and materials than the
turntable the models were trained on). Several model files can be compared in one run:

    tlessbot bench recognition --models ../shared/data/tless_models_cad_stl \\
        --classifier m_sgd.npz m_perceptron.npz m_pa1.npz m_pa2.npz --scenes 60 \\
        --real-data ../shared/data --out reports/recognition

Writes <out>/recognition.md (Table 1 shape + timing) and <out>/confusion_<model file stem>.png.

With --templates, the parts (not the crops) are also scored as the graph names them: the
scores of a part's crops in both views are summed (two-view vote), and its best --candidates
classes are verified by fitting their templates to the part's side-view cloud
(``PerceptionPipeline.estimate_poses``; the first candidate is kept when its fit reaches
``verify_accept_fitness``). Parts seen by the side camera (>= --min-pixels) are scored.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import SIDE


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', type=Path, required=True, help='CAD model folder')
    parser.add_argument('--classifier', type=Path, nargs='+', required=True,
                        help='one or more model .npz files (from tlessbot train)')
    parser.add_argument('--scenes', type=int, default=40, help='simulated two-view frames')
    parser.add_argument('--seed', type=int, default=1000,
                        help='simulator seed (keep it different from the training seed)')
    parser.add_argument('--min-pixels', type=int, default=100,
                        help='skip crops with fewer visible pixels')
    parser.add_argument('--real-data', type=Path,
                        help='shared data folder: also test the real T-LESS crops in it')
    parser.add_argument('--templates', type=Path,
                        help='template database: also score two-view voting and pose '
                             "verification per part (the graph's recognition)")
    parser.add_argument('--candidates', type=int, default=3,
                        help='classes verified by the pose fit per part (with --templates)')
    parser.add_argument('--lookalike-tolerance', type=float, default=0.002,
                        help='m: depth difference that a view of a look-alike pair must show')
    parser.add_argument('--min-difference', type=float, default=0.005,
                        help='share of visible pixels that must show it for the crop to count '
                             'as telling the look-alikes apart')
    parser.add_argument('--out', type=Path, default=Path('reports/recognition'))


def simulated_crops(models, scenes: int, seed: int, min_pixels: int):
    """Ground-truth-mask crops of simulated frames: (crops list per view, labels, visib)."""
    from tqdm import tqdm

    from tlessbot_ros.sim.simulator import Simulator

    simulator = Simulator(models, seed=seed)
    views = []  # (rgb, masks, labels, visib, depth kwargs)
    frames = []
    for index in tqdm(range(scenes), desc='simulate', unit='frame'):
        frame = simulator.frame(index)
        frames.append(frame)
        for view in frame.views.values():
            gts = [g for g in view.gt if g.px_count_visib >= min_pixels]
            if gts:
                depth = {'depth_m': view.depth_mm.astype(np.float32) / 1000.0,
                         'K': view.intrinsics.K, 'T_world_camera': view.T_world_camera}
                views.append((view.rgb, [g.mask_visib for g in gts],
                              np.array([g.obj_id for g in gts]),
                              np.array([g.visib_fract for g in gts]), depth))
    return views, frames


def lookalike_difference(models, frames, min_pixels: int, tolerance_m: float
                         ) -> tuple[np.ndarray, dict[int, tuple[int, ...]]]:
    """Per crop (in :func:`simulated_crops` order): the share of its visible pixels where its
    look-alike part, at the same ground-truth pose, would show another depth (NaN for parts
    without a look-alike), and the look-alike pairs found among the models."""
    from tlessbot_ros.core.common import raycasting_scene
    from tlessbot_ros.core.pose import lookalike_pairs, visible_difference

    meshes = {i: (m.vertices, m.faces) for i, m in models.items()}
    pairs = lookalike_pairs(meshes, tolerance_m=tolerance_m)
    scenes = {i: raycasting_scene(*meshes[i]) for i in pairs}
    shares = []
    for frame in frames:
        for view in frame.views.values():
            for gt in view.gt:
                if gt.px_count_visib < min_pixels:
                    continue
                others = pairs.get(gt.obj_id, ())
                shares.append(min((visible_difference(
                    scenes[gt.obj_id], scenes[other], gt.T_camera_object, view.intrinsics,
                    gt.mask_visib, tolerance_m=tolerance_m) for other in others), default=np.nan))
    return np.asarray(shares, np.float64), pairs


def part_recognition(model, templates, frames, min_pixels: int, candidates: int
                     ) -> dict[str, np.ndarray]:
    """Per part seen by the side camera: truth, side-crop class, two-view vote, verified class,
    and the verification time in ms. Ground-truth masks are the instance labels."""
    from tqdm import tqdm

    from tlessbot_ros.core.pipeline import ClassifyParams, PerceptionPipeline, ViewInput

    pipeline = PerceptionPipeline(classifier=model, templates=templates,
                                  classify_params=ClassifyParams(min_instance_px=min_pixels,
                                                                 class_candidates=candidates))
    pipeline.pose_estimator.warm_up()
    rows = {'truth': [], 'side': [], 'vote': [], 'verified': [], 'ms': []}
    for frame in tqdm(frames, desc='verify', unit='frame'):
        labels, inputs, rgb = {}, {}, {}
        for name, view in frame.views.items():
            labels[name] = (view.instance + 1).astype(np.uint16)   # -1 background -> 0
            rgb[name] = view.rgb
            inputs[name] = ViewInput(view.rgb, view.depth_mm.astype(np.float32) / 1000.0,
                                     view.intrinsics, view.T_world_camera)
        side_only = {SIDE: labels[SIDE]}
        seen = [i for i in np.unique(labels[SIDE]) if i and
                np.count_nonzero(labels[SIDE] == i) >= min_pixels]
        if not seen:
            continue
        side_guess = pipeline.classify({SIDE: rgb[SIDE]}, side_only, views=inputs)
        vote = pipeline.classify(rgb, labels, views=inputs)
        t0 = time.perf_counter()
        detections = {d.instance_id: d for d in pipeline.estimate_poses(
            inputs, side_only, {i: vote[i].candidates for i in seen if i in vote})}
        per_part_ms = 1e3 * (time.perf_counter() - t0) / len(seen)
        for instance in seen:
            truth = frame.views[SIDE].gt[instance - 1].obj_id
            rows['truth'].append(truth)
            rows['side'].append(side_guess[instance].obj_id if instance in side_guess else 0)
            rows['vote'].append(vote[instance].obj_id if instance in vote else 0)
            found = detections.get(instance)
            rows['verified'].append(found.obj_id if found is not None else rows['vote'][-1])
            rows['ms'].append(per_part_ms)
    return {key: np.asarray(values) for key, values in rows.items()}


def real_crops(data: Path):
    """Real T-LESS crops in the shared data: list of (name, rgb, mask or None, obj_id, K or
    None); K where the images' camera is known (the Primesense training images), which is the
    unit of a model's box-size features."""
    import cv2
    import yaml

    out = []
    for obj_id in (19, 21):
        for path in sorted((data / 'tless_template_pose_demo' / f'tless_{obj_id}').glob(
                'query_*.png')):
            rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
            out.append((f'tless_{obj_id}/{path.name}', rgb, None, obj_id, None))
    primesense = data / 'tless_v2_dsynth_sample' / 't-less_v2' / 'train_primesense' / '02'
    info_path = primesense / 'info.yml'
    info = yaml.safe_load(info_path.read_text()) if info_path.is_file() else {}
    for path in sorted((primesense / 'rgb').glob('*.png')):
        entry = info.get(int(path.stem), {}) if path.stem.isdigit() else {}
        K = np.reshape(entry['cam_K'], (3, 3)) if 'cam_K' in entry else None
        rgb = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
        mask = cv2.imread(str(primesense / 'mask' / path.name), cv2.IMREAD_GRAYSCALE)
        out.append((f'primesense_02/{path.name}', rgb, None if mask is None else mask > 127, 2,
                    K))
    return out


def time_per_crop(model, views, repeats: int = 3) -> float:
    """Median seconds per crop of normalise + HOG (+ shape) + predict, frames of 5 crops."""
    per_crop = []
    for rgb, masks, _, _, depth in views:
        masks = (masks * 5)[:5]  # a frame of 5 crops
        for _ in range(repeats):
            t0 = time.perf_counter()
            model.predict(model.describe(rgb, masks, **depth))
            per_crop.append((time.perf_counter() - t0) / len(masks))
    return float(np.median(per_crop))


def confusion_png(path: Path, matrix: np.ndarray, ids: list[int], title: str) -> None:
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    rows = matrix / np.maximum(matrix.sum(axis=1, keepdims=True), 1)
    fig, ax = plt.subplots(figsize=(8, 7))
    image = ax.imshow(rows, cmap='viridis', vmin=0, vmax=1)
    names = [f'{i:02d}' for i in ids]
    ax.set_xticks(range(len(ids)), names, rotation=90, fontsize=7)
    ax.set_yticks(range(len(ids)), names, fontsize=7)
    ax.set_xlabel('predicted obj')
    ax.set_ylabel('true obj')
    ax.set_title(title, fontsize=9)
    fig.colorbar(image, ax=ax, label='fraction of true-class crops')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def lookalike_table(models, frames, labels, columns, *, min_pixels: int, tolerance_m: float,
                    min_difference: float) -> list[str]:
    """Markdown: accuracy on the crops of look-alike parts, split by whether the view shows
    what tells them apart (see :mod:`tlessbot_ros.core.pose.lookalike`): a view shows it when
    at least ``min_difference`` of its visible pixels differ by more than ``tolerance_m``."""
    share, pairs = lookalike_difference(models, frames, min_pixels, tolerance_m)
    if not pairs:
        return []
    has_twin = np.isfinite(share)
    shows = has_twin & (share >= min_difference)
    hidden = has_twin & ~shows
    names = ', '.join(f'obj_{a:02d}/obj_{b:02d}' for a, others in sorted(pairs.items())
                      for b in others if a < b)
    rows = [('all crops', np.ones(len(labels), bool)),
            ('crops of look-alike parts', has_twin),
            (f'... whose view shows the difference (>= {100 * min_difference:.1f} % of '
             f'the visible pixels, > {1e3 * tolerance_m:.0f} mm)', shows),
            ('... whose view does not (the look-alike would look the same)', hidden),
            ('all crops but those', ~hidden)]
    lines = ['', '## Look-alike parts', '',
             f'Pairs sharing >= 80 % of their surface within {1e3 * tolerance_m:.0f}'
             f' mm: {names}. A crop of one of them is checked by rendering the other at the '
             'same ground-truth pose over its visible mask.', '',
             '| crops | n | ' + ' | '.join(header for header, _, _ in columns) + ' |',
             '|---|---|' + '---|' * len(columns)]
    for name, sel in rows:
        lines.append(f'| {name} | {int(sel.sum())} | ' + ' | '.join(
            f'{100 * np.mean(pred[sel] == labels[sel]):.1f}' if sel.any() else '–'
            for _, pred, _ in columns) + ' |')
    cells = []
    for _, pred, _ in columns:
        twin_named = np.array([hidden[k] and int(pred[k]) in pairs.get(int(labels[k]), ())
                               for k in range(len(labels))], bool)
        cells.append(f'{100 * np.mean((pred == labels) | twin_named):.1f}')
    lines.append(f'| all crops, the look-alike counted right where the view cannot show the '
                 f'difference | {len(labels)} | ' + ' | '.join(cells) + ' |')
    return lines


def crop_pose_stage(model, templates, frames, min_pixels: int, scores: np.ndarray, *,
                    candidates: int, verify: bool) -> tuple[np.ndarray, list[float]]:
    """Per crop (in :func:`simulated_crops` order), its class after the pose stage, run on that
    crop's view alone (``PerceptionPipeline.estimate_poses``): with ``verify``, the classes
    ``PerceptionPipeline.verification_candidates`` gives for its (N, C) ``scores`` and its
    view (the best ``candidates``; in the top view only when the classifier is unsure) are
    fitted and verified, then a part with a look-alike is checked against it; without, only
    the crops whose first class has a look-alike are fitted, with that class, for the check.
    Returns the classes and the ms of the pose stage of each fitted crop.

    (Top-view crops are fitted only when the classifier is unsure, because a top view's
    cloud, mostly one face, fits many parts: docs/bench/code-figures.md.)"""
    from tlessbot_ros.core.pipeline import ClassifyParams, PerceptionPipeline, ViewInput

    pipeline = PerceptionPipeline(classifier=model, templates=templates,
                                  classify_params=ClassifyParams(min_instance_px=min_pixels,
                                                                 class_candidates=candidates))
    pipeline.warm_up()  # caches built now, not inside the first crop's timing
    prediction = model.predict_scores(scores, reject_margin=0.0)
    ranked = model.ranked_classes(scores, candidates)
    classes, times, k = prediction.class_ids.copy(), [], 0
    for frame in frames:
        for name, view in frame.views.items():
            data = None
            labels = (view.instance + 1).astype(np.uint16)   # -1 background -> 0
            for instance, gt in enumerate(view.gt, start=1):
                if gt.px_count_visib < min_pixels:
                    continue
                obj_id = int(classes[k])
                fit = pipeline.verification_candidates(
                    obj_id, float(prediction.margins[k]), ranked[k], name) if verify \
                    else (obj_id,)
                if len(fit) > 1 or (pipeline.lookalike is not None and obj_id in
                                    pipeline.lookalike):
                    data = data or ViewInput(view.rgb, view.depth_mm.astype(np.float32) / 1000.0,
                                             view.intrinsics, view.T_world_camera)
                    t0 = time.perf_counter()
                    found = pipeline.estimate_poses({name: data}, {name: labels}, {instance: fit})
                    times.append(1e3 * (time.perf_counter() - t0))
                    if found and found[0].instance_id == instance:
                        classes[k] = found[0].obj_id
                k += 1
    return classes, times


def classifier_columns(classifiers: dict, views, frames, templates, args: argparse.Namespace
                       ) -> tuple[dict, list]:
    """Each classifier's crop predictions: {path: (model, predicted (N,), s per crop)} and the
    table's columns [(header, predicted classes (N,), timing cell)], with the look-alike check
    and the pose stage's columns after each classifier's when ``templates`` is given."""
    results = {}
    columns = []
    for path, model in classifiers.items():
        features = np.concatenate([model.describe(rgb, masks, **depth)
                                   for rgb, masks, _, _, depth in views])
        scores = model.decision_function(features)
        predicted = model.predict_scores(scores, reject_margin=0.0).class_ids
        results[path] = (model, predicted, time_per_crop(model, views[:60]))
        columns.append((f'{model.kind}, {"ours" if model.uses_depth else "paper"} ({path.name})',
                        predicted, f'{1e3 * results[path][2]:.3f}'))
        if templates is None:
            continue
        for header, verify in (('+ look-alike check', False),
                               ('+ pose stage (verification, look-alike check)', True)):
            classes, ms = crop_pose_stage(model, templates, frames, args.min_pixels, scores,
                                          candidates=args.candidates, verify=verify)
            columns.append((header, classes, f'+{np.median(ms) if ms else 0:.1f} per fitted '
                            f'crop ({len(ms)} fitted, {int(np.sum(classes != predicted))} '
                            'changed)'))
    return results, columns


def crop_table(ids: list[int], labels: np.ndarray, visib: np.ndarray, columns: list
               ) -> list[str]:
    """Markdown rows of the per-object crop table: one row per object, then all crops, the
    mean over objects, the crops at least half visible and the timing row."""
    lines = []
    for obj_id in ids:
        sel = labels == obj_id
        cells = [f'{100 * np.mean(pred[sel] == obj_id):.1f}' if sel.any() else '–'
                 for _, pred, _ in columns]
        lines.append(f'| obj_{obj_id:02d} | {int(sel.sum())} | ' + ' | '.join(cells) + ' |')
    overall = [float(np.mean(pred == labels)) for _, pred, _ in columns]
    per_object = [float(np.mean([np.mean(pred[labels == i] == i) for i in ids
                                 if (labels == i).any()])) for _, pred, _ in columns]
    lines.append('| **all (crops)** | ' + f'{len(labels)} | ' + ' | '.join(
        f'**{100 * value:.1f}**' for value in overall) + ' |')
    lines.append('| mean over objects | | ' + ' | '.join(
        f'{100 * value:.1f}' for value in per_object) + ' |')
    visible = visib >= 0.5
    lines.append('| crops with visib_fract >= 0.5 | ' + f'{int(visible.sum())} | ' + ' | '.join(
        f'{100 * np.mean(pred[visible] == labels[visible]):.1f}'
        for _, pred, _ in columns) + ' |')
    load = ', '.join(f'{v:.2f}' for v in os.getloadavg())
    lines.append('| normalise+HOG(+shape)+predict, ms/crop (median, frames of 5) | | '
                 + ' | '.join(cell for _, _, cell in columns) + ' |')
    lines += ['', f'Load average (1, 5, 15 min) when timed: {load} on {os.cpu_count()} cores '
              '(timings scale with it; the goal is <= 1 ms on an idle core).']
    return lines


def confusion_lines(results: dict, ids: list[int], labels: np.ndarray, out: Path,
                    overall_by_path: dict) -> list[str]:
    """Write each classifier's confusion matrix to ``out``/confusion_<stem>.png; one list line
    each."""
    lines = []
    index = {obj_id: k for k, obj_id in enumerate(ids)}
    for path, (model, predicted, _) in results.items():
        matrix = np.zeros((len(ids), len(ids)), np.int64)
        for truth, guess in zip(labels, predicted):
            if guess in index:
                matrix[index[truth], index[guess]] += 1
        png = out / f'confusion_{path.stem}.png'
        confusion_png(png, matrix, ids, f'{model.kind} ({path.name}): '
                      f'{100 * overall_by_path[path]:.1f} % top-1, {len(labels)} simulated crops')
        lines.append(f'- confusion matrix of {model.kind} ({path.name}): {png.name}')
    return lines


def part_lines(results: dict, templates, frames, ids: list[int], args: argparse.Namespace
               ) -> list[str]:
    """The section on parts as the graph names them (two-view vote, pose verification)."""
    lines = ['', '## Parts as the graph names them (two-view vote, pose verification)', '',
             f'Parts seen by the side camera; verification fits the best {args.candidates} '
             f"classes' templates ({args.templates.name}) to the side-view cloud.", '',
             '| model | parts | side crop | two-view vote | + pose verification '
             '| pose + verification ms/part |', '|---|---|---|---|---|---|']
    for path, (model, _, _) in results.items():
        parts = part_recognition(model, templates, frames, args.min_pixels, args.candidates)
        truth = parts['truth']
        cells = [f'{100 * np.mean(parts[key] == truth):.1f}'
                 for key in ('side', 'vote', 'verified')]
        lines.append(f'| {model.kind} ({path.name}) | {len(truth)} | ' + ' | '.join(cells)
                     + f' | {np.median(parts["ms"]):.0f} (median) |')
        lines += ['', '| obj | parts | side crop | + pose verification |', '|---|---|---|---|']
        for obj_id in ids:
            sel = truth == obj_id
            if sel.any():
                lines.append(f'| obj_{obj_id:02d} | {int(sel.sum())} | '
                             f'{100 * np.mean(parts["side"][sel] == obj_id):.1f} | '
                             f'{100 * np.mean(parts["verified"][sel] == obj_id):.1f} |')
    return lines


def real_crop_lines(results: dict, real_data: Path) -> list[str]:
    """The section on the real T-LESS crops: each classifier's guess per crop."""
    lines = ['', '## Real T-LESS crops', '',
             'No depth with these crops: an "ours" model fills the shape part with its '
             'training mean (the HOG decides alone), so read them as paper features.', '',
             '| crop | mask | truth | ' + ' | '.join(m.kind for m, _, _ in
                                                     results.values()) + ' |',
             '|---|---|---|' + '---|' * len(results)]
    for name, rgb, mask, obj_id, K in real_crops(real_data):
        guesses = []
        for model, _, _ in results.values():
            boxes = [(0, 0, rgb.shape[1], rgb.shape[0])] if mask is None else None
            features = model.describe(rgb, None if mask is None else [mask], boxes, K=K)
            guess = int(model.predict(features, reject_margin=0.0).class_ids[0])
            guesses.append(f'obj_{guess:02d}' + (' ✓' if guess == obj_id else ''))
        lines.append(f'| {name} | {"GT" if mask is not None else "none"} | obj_{obj_id:02d} | '
                     + ' | '.join(guesses) + ' |')
    return lines


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.core.recognise import BACKGROUND_ID, LinearClassifier
    from tlessbot_ros.io.models import load_models

    classifiers = {path: LinearClassifier.load(path) for path in args.classifier}
    ids = sorted(set().union(*(m.class_ids.tolist() for m in classifiers.values()))
                 - {BACKGROUND_ID})
    models = load_models(args.models, ids)
    views, frames = simulated_crops(models, args.scenes, args.seed, args.min_pixels)
    labels = np.concatenate([v[2] for v in views])
    visib = np.concatenate([v[3] for v in views])
    args.out.mkdir(parents=True, exist_ok=True)
    templates = None
    if args.templates is not None:
        from tlessbot_ros.core.pose import TemplateDatabase

        templates = TemplateDatabase.load(args.templates)
    results, columns = classifier_columns(classifiers, views, frames, templates, args)
    lines = ['# Recognition on simulated two-view scenes', '',
             f'{len(labels)} crops (ground-truth visible masks, >= {args.min_pixels} px) from '
             f'{args.scenes} frames, simulator seed {args.seed}; objects {len(ids)}.', '',
             '| obj | crops | ' + ' | '.join(header for header, _, _ in columns) + ' |',
             '|---|---|' + '---|' * len(columns)]
    if templates is not None:
        lines[2] += (" Each crop also goes through the pose stage on its own view's depth: "
                     '"+ look-alike check" fits the crops named as a part with a look-alike '
                     'with that part and compares it with its look-alike at the fitted pose; '
                     '"+ pose stage" also fits and verifies the best '
                     f'{args.candidates} classes (of a top-view crop only when the classifier '
                     'is unsure: ``top_view_verify_below_margin``), as the graph does.')
    lines += crop_table(ids, labels, visib, columns)
    overall_by_path = {p: float(np.mean(pred == labels)) for p, (_, pred, _) in results.items()}
    best = max(results, key=lambda p: overall_by_path[p])
    lines += ['', f'Best classifier: **{results[best][0].kind}** ({best.name}) with '
              f'{100 * overall_by_path[best]:.1f} % top-1 over all crops '
              '(paper: 70.43 % on its own scenes).']
    lines += lookalike_table(models, frames, labels, columns, min_pixels=args.min_pixels,
                             tolerance_m=args.lookalike_tolerance,
                             min_difference=args.min_difference)
    lines += confusion_lines(results, ids, labels, args.out, overall_by_path)
    if templates is not None:
        lines += part_lines(results, templates, frames, ids, args)
    if args.real_data is not None:
        lines += real_crop_lines(results, args.real_data)
    report = args.out / 'recognition.md'
    report.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    print('\n'.join(lines))
    print(f'\nwrote {report}')
    return 0
