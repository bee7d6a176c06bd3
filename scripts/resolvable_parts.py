"""Which ground-truth parts of an evaluated cell the rig can resolve at 5°, and the cell's
5 cm / 5° over all parts and over the resolvable parts only.

    PYTHONPATH=. python scripts/resolvable_parts.py SCENES MODELS ESTIMATES_CSV
        [--manifest PARTS/manifest.json] [--label CELL] [--no-header] [--parts]

(PYTHONPATH=.: a script's own folder comes first on the path, so without it the installed
package, maybe another tree's, is imported.)

SCENES: a scenes folder of ``tlessbot bench own-parts`` (``test_side`` scored, ``test_top`` the
second camera); MODELS: its models folder (models_info.json: the listed symmetries);
ESTIMATES_CSV: ``tlessbot evaluate``'s estimates.csv. The targets and their outcome are those
of ``tlessbot evaluate`` (visib_fract >= 0.3, estimates matched per class, 5 cm / 5° modulo the
listed symmetries: the "all" column is the report's). Each target is measured at its TRUE pose,
both cameras, the frame's other parts hiding it
(:func:`tlessbot_ros.core.pose.resolvability.resolvability`, the settings of
``ObservabilityParams``: a turn or twin that changes fewer than 20 pixels is not seen), the
symmetries left out being those the scoring uses (listed, else detected as evaluate does). Twins:
the manifest's look-alikes (``--manifest``), else ``lookalike_pairs`` of the models (as the
templates list them). The estimates play no part in the measure.

Prints a Markdown table row per cell: targets, 5 cm / 5° over all, resolvable targets and their
5 cm / 5°, the unresolvable targets by cause (an instance may have several) and how many of
those were scored right all the same; ``--parts``: one line per unresolvable target.
"""
from __future__ import annotations

import argparse
import json
from collections import Counter, defaultdict
from dataclasses import replace
from pathlib import Path

from tqdm import tqdm

from tlessbot_ros.core.common import SIDE, TOP
from tlessbot_ros.core.metrics import is_correct_cm_deg, pose_error
from tlessbot_ros.core.pose import ObservabilityParams, ViewOfTable, lookalike_pairs
from tlessbot_ros.core.pose.resolvability import CAUSES, posed_scene, resolvability
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.io.bop_results import read_results
from tlessbot_ros.io.models import load_models
from tlessbot_ros.tools.support.eval_scoring import MIN_VISIB_FRACT, match_poses, scoring_model
from tlessbot_ros.tools.support.observability import part_shape

HEADER = ('| cell | parts | all 5cm/5° | resolvable | resolvable 5cm/5° | '
          + ' | '.join(f'not: {c}' for c in CAUSES) + ' | not resolvable, right |\n'
          + '|---' * (6 + len(CAUSES)) + '|')


def _twins(models: dict, manifest: Path | None) -> dict[int, tuple[int, ...]]:
    """{obj_id: look-alike ids}: the manifest's lists, else the templates' rule."""
    if manifest is None:
        return lookalike_pairs({i: (m.vertices, m.faces) for i, m in models.items()})
    parts = json.loads(manifest.read_text())['parts']
    ids = {p['name']: p['id'] for p in parts}
    return {p['id']: tuple(ids[n] for n in p['lookalikes'] if n in ids)
            for p in parts if p['lookalikes']}


def measure_cell(scenes: Path, models_dir: Path, estimates: Path, manifest: Path | None,
                 label: str) -> list[dict]:
    """One row per target: where, obj, ok (5 cm / 5°) and its :class:`Resolvability`."""
    models = load_models(models_dir)
    twins = _twins(models, manifest)
    pairs = list(zip(read_split(scenes, f'test_{SIDE}', load_masks=False),
                     read_split(scenes, f'test_{TOP}', load_masks=False)))
    seen = {g.obj_id for side, _ in pairs for g in side.gt}
    seen |= {i for obj_id in seen for i in twins.get(obj_id, ())}
    # the symmetries the scoring uses (listed, else detected): the measure leaves them out
    scoring = {i: scoring_model(i, m.vertices, m.faces, m.diameter_m, m.listed_symmetries())
               for i, m in models.items() if i in seen}
    shapes = {i: part_shape(models[i], s.symmetries) for i, s in scoring.items()}
    by_frame = defaultdict(list)
    for est in read_results(estimates):
        by_frame[(est.scene_id, est.im_id)].append(est)
    params = ObservabilityParams()
    rows = []
    for side, top in tqdm(pairs, desc=label, unit='frame'):
        views = [ViewOfTable(im.intrinsics, im.T_world_camera) for im in (side, top)]
        matches = match_poses(side, by_frame[(side.scene_id, side.im_id)], scoring)
        posed = [(models[g.obj_id], side.T_world_camera @ g.T_camera_object) for g in side.gt]
        for k, gt in enumerate(side.gt):
            if gt.visib_fract is None or gt.visib_fract < MIN_VISIB_FRACT:
                continue
            est = matches.get(k)
            ok = est is not None and is_correct_cm_deg(pose_error(
                est.T_camera_object, gt.T_camera_object, scoring[gt.obj_id].symmetries))
            others = posed_scene([(m.vertices, m.faces, T) for j, (m, T) in enumerate(posed)
                                  if j != k])
            found = resolvability(shapes[gt.obj_id], posed[k][1], views, params, others=others,
                                  twins={i: shapes[i] for i in twins.get(gt.obj_id, ())})
            rows.append({'scene': side.scene_id, 'im': side.im_id, 'gt': k, 'obj': gt.obj_id,
                         'ok': bool(ok), 'found': found})
    return rows


def table_row(label: str, rows: list[dict]) -> str:
    """The cell's Markdown row (see the module's docstring)."""
    def share(group: list[dict]) -> str:
        return f'{sum(r["ok"] for r in group) / len(group):.3f}' if group else '-'

    resolvable = [r for r in rows if r['found'].resolvable]
    unresolvable = [r for r in rows if not r['found'].resolvable]
    causes = Counter(c for r in rows for c in r['found'].causes)
    return (f'| {label} | {len(rows)} | {share(rows)} | {len(resolvable)} | '
            f'{share(resolvable)} | ' + ' | '.join(str(causes[c]) for c in CAUSES)
            + f' | {sum(r["ok"] for r in unresolvable)} of {len(unresolvable)} |')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('scenes', type=Path)
    ap.add_argument('models', type=Path)
    ap.add_argument('estimates', type=Path)
    ap.add_argument('--manifest', type=Path, help="a parts folder's manifest.json: its "
                    'look-alikes (else found from the models)')
    ap.add_argument('--label', help="the cell's name in the table (default: the scenes folder)")
    ap.add_argument('--no-header', action='store_true', help='the row alone')
    ap.add_argument('--parts', action='store_true', help='one line per unresolvable part')
    ap.add_argument('--also-min-px', type=int, nargs='*', default=[], metavar='PX',
                    help='rows at these thresholds too (a check of how much the split '
                    "hangs on the measure's 20 px)")
    args = ap.parse_args()
    label = args.label or args.scenes.resolve().name
    rows = measure_cell(args.scenes, args.models, args.estimates, args.manifest, label)
    if args.parts:
        for r in (r for r in rows if not r['found'].resolvable):
            unseen = [f'{name} {angle:.0f}° ({px} px)'
                      for name, angle, px in r['found'].unseen_turns]
            unseen += [f'twin obj {i} ({px} px)' for i, px in r['found'].unseen_twins]
            print(f"scene {r['scene']} im {r['im']:3d} gt {r['gt']} obj {r['obj']:3d} "
                  f"{'ok   ' if r['ok'] else 'wrong'} unseen: {', '.join(unseen)}")
        names = ({q['id']: q['name'] for q in json.loads(args.manifest.read_text())['parts']}
                 if args.manifest else {})
        for obj in sorted({r['obj'] for r in rows}):
            mine = [r for r in rows if r['obj'] == obj]
            lost = [r for r in mine if not r['found'].resolvable]
            if lost:
                name = names.get(obj, f'obj_{obj:02d}')
                print(f'{label}: obj {obj} {name}: {len(lost)} of {len(mine)} '
                      f"unresolvable ({sum(r['ok'] for r in lost)} right), resolvable right "
                      f"{sum(r['ok'] for r in mine if r['found'].resolvable)} of "
                      f'{len(mine) - len(lost)}')
    if not args.no_header:
        print(HEADER)
    print(table_row(label, rows))
    for px in args.also_min_px:
        print(table_row(f'{label} (< {px} px)',
                        [{**r, 'found': replace(r['found'], min_px=px)} for r in rows]))


if __name__ == '__main__':
    main()
