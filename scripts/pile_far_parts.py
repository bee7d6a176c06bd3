"""Every part scored ``far`` (its class named, no pose of it within 5 cm), traced through the
pose stage: the region it was fitted in, what the fits of that region became, where its
class's poses went.

    python scripts/pile_far_parts.py SCENES PARTS ESTIMATES_CSV [--tsv OUT.tsv]

SCENES: a scenes folder of the bench (scored in ``test_side``); PARTS: its parts folder
(models/, classifier.npz, templates.npz) or ``T`` for the packaged T-LESS set; ESTIMATES_CSV:
``tlessbot evaluate``'s estimates.csv of the same code (the far parts are read from it, only
their frames are run again). The pipeline runs as ``tlessbot evaluate`` does, with the fused
labels (the regions the pose stage gets), every fit and the fragment filter's decisions
recorded. Per far part:

- ``twins``: how many other parts of its class the frame holds; ``twin_posed``: every pose of
  its class lies within 5 cm of one of its twins (the part itself got none);
- ``region``: the fused region over most of its pixels in the view it is best seen in:
  ``alone`` (>= 60 % of the region is the part, it covers >= 50 % of the part), ``fragment``
  (mostly the part, under half of it), ``with twin`` / ``with other`` (one more part
  >= 20 % of it), ``several`` (two more), ``other`` (mostly another part), ``none``;
- ``fits``: each fit made on that region (class [candidates], distance of its centre to the
  part / the nearest other part and its distance, kept / dropped by the fragment filter);
- ``cause``: the first that holds: ``no region``; ``dropped`` (a fit of its class within 5 cm
  dropped by the fragment filter); ``region KIND`` (the region is not the part's alone);
  ``named other`` (its own region fitted as another class; ``(its class offered)``: its class
  was among the candidates); ``no fit``; ``pose off`` (its own region fitted as its class,
  the pose > 5 cm off).
"""
from __future__ import annotations

import argparse
import csv
import json
import sys
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from tlessbot_ros.core import pipeline as pipeline_module
from tlessbot_ros.core.common import SIDE, TOP
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.tools.support.eval_frames import _first_pipeline, two_view_frames
from tlessbot_ros.tools.support.overrides import stage_overrides

record: dict = {}
PACKAGED = Path(__file__).resolve().parents[1] / 'tlessbot_ros' / 'data'


def _hook() -> None:
    """Record the fused labels, every fitted job and the fragment filter (module attributes
    replaced; the pipeline looks them up there)."""
    fuse, arbiter_of = pipeline_module.fuse_views, pipeline_module.one_part_filter
    fit_part = PerceptionPipeline.fit_part

    def fused(*args, **kw):
        out = fuse(*args, **kw)
        record['fused'] = {k: v.copy() for k, v in out.labels.items()}
        return out

    def arbiter(*args, **kw):
        record['arbiter'] = arbiter_of(*args, **kw)
        return record['arbiter']

    def fitted(self, job):
        fit_part(self, job)
        jobs = record.setdefault('jobs', [])
        if not any(j is job for j in jobs):   # a part refitted is listed once
            jobs.append(job)

    pipeline_module.fuse_views, pipeline_module.one_part_filter = fused, arbiter
    PerceptionPipeline.fit_part = fitted   # type: ignore[method-assign]


def _far_parts(scenes: Path, estimates: Path) -> dict[tuple[int, int], list[int]]:
    """{(scene, im): [gt index, ...]} of the parts scored far in ``estimates``."""
    by_key: dict[tuple[int, int, int], list[np.ndarray]] = defaultdict(list)
    with estimates.open() as f:
        for row in csv.DictReader(f):
            by_key[(int(row['scene_id']), int(row['im_id']), int(row['obj_id']))].append(
                np.array(row['t'].split(), float) / 1000)
    far: dict[tuple[int, int], list[int]] = defaultdict(list)
    for scene in sorted((scenes / 'test_side').iterdir()):
        gt = json.loads((scene / 'scene_gt.json').read_text())
        for im, parts in gt.items():
            for k, part in enumerate(parts):
                found = by_key.get((int(scene.name), int(im), part['obj_id']), [])
                t = np.array(part['cam_t_m2c']) / 1000
                if found and min(np.linalg.norm(x - t) for x in found) > 0.05:
                    far[(int(scene.name), int(im))].append(k)
    return far


def _region(fused: np.ndarray, masks: list, k: int, obj_ids: list[int]) -> tuple[int, str, str]:
    """The fused instance over most of part ``k``'s pixels, its kind (see the module) and
    its make-up (part index: share of the region)."""
    mask = masks[k]
    values = fused[mask]
    values = values[values > 0]
    if mask is None or not values.size:
        return 0, 'none', '-'
    inst = int(np.bincount(values).argmax())
    region = fused == inst
    shares = sorted(((float((region & m).sum()) / region.sum(), j) for j, m in enumerate(masks)
                     if m is not None and (region & m).any()), reverse=True)
    own = next((s for s, j in shares if j == k), 0.0)
    others = [(s, j) for s, j in shares if j != k and s >= 0.2]
    covers = float((region & mask).sum()) / mask.sum()
    if shares and shares[0][1] != k and shares[0][0] >= 0.6:
        kind = 'other'
    elif len(others) >= 2:
        kind = 'several'
    elif others:
        kind = 'with twin' if obj_ids[others[0][1]] == obj_ids[k] else 'with other'
    elif own >= 0.6 and covers < 0.5:
        kind = 'fragment'
    else:
        kind = 'alone'
    make_up = ' '.join(f'{j}:{s:.2f}' for s, j in shares[:4]) + f' cov {covers:.2f}'
    return inst, kind, make_up


def _centre(views: dict, detection) -> np.ndarray | None:
    if detection.pose is None:
        return None
    return (views[detection.view].T_world_camera @ detection.pose.T_camera_object)[:3, 3]


def _fate(arbiter, detection, kept_ids: set[int]) -> str:
    if id(detection) in kept_ids:
        return 'kept'
    if arbiter is None or not any(d is detection for d in arbiter.dropped):
        return 'gone'
    if id(detection) in arbiter.erased:
        return 'dropped(band)'
    keeper = arbiter.kept_by.get(id(detection))
    return 'dropped' if keeper is None else f'dropped(joins {keeper.instance_id})'


def _trace_part(k: int, side, top, views: dict, result, names: dict) -> dict:
    """One far part's row (see the module)."""
    gt_all = side.gt
    obj_ids = [g.obj_id for g in gt_all]
    centres = [(side.T_world_camera @ g.T_camera_object)[:3, 3] for g in gt_all]
    gt = gt_all[k]
    counts = {v: int(im.gt[k].mask.sum()) if im.gt[k].mask is not None else 0
              for v, im in ((SIDE, side), (TOP, top))}
    view = max(counts, key=lambda v: counts[v])
    image = side if view == SIDE else top
    inst, kind, make_up = _region(record['fused'][view], [g.mask for g in image.gt], k, obj_ids)
    arbiter = record.get('arbiter')
    kept_ids = {id(d) for d in result.detections}

    def where(c: np.ndarray) -> tuple[float, str]:
        d_own = float(np.linalg.norm(c - centres[k]))
        near = min((float(np.linalg.norm(c - centres[j])), j) for j in range(len(gt_all))
                   if j != k) if len(gt_all) > 1 else (np.inf, -1)
        return d_own, f'{1e3 * d_own:.0f}mm/{names.get(obj_ids[near[1]], "-")}' \
            f'@{1e3 * near[0]:.0f}mm'

    fits, own_class_dropped, own_class_fit, offered = [], False, False, False
    for job in record.get('jobs', []):
        d = job.detection
        c = _centre(views, d)
        if c is None:
            continue
        d_own, text = where(c)
        fate = _fate(arbiter, d, kept_ids)
        if d.obj_id == gt.obj_id and d_own <= 0.05 and fate.startswith('dropped'):
            own_class_dropped = True
        if d.instance_id == inst:
            own_class_fit |= d.obj_id == gt.obj_id
            offered |= gt.obj_id in job.candidates
            cands = '/'.join(names.get(c_, str(c_)) for c_ in job.candidates)
            fits.append(f'{names.get(d.obj_id, d.obj_id)}[{cands}] {text} {fate}')
    second = any(d.second is not None and d.obj_id == gt.obj_id and np.linalg.norm(
        (views[d.view].T_world_camera @ d.second.T_camera_object)[:3, 3] - centres[k]) <= 0.05
        for d in result.detections)
    same_class = [_centre(views, d) for d in result.detections
                  if d.obj_id == gt.obj_id and d.pose is not None]
    twins = [j for j in range(len(gt_all)) if j != k and obj_ids[j] == gt.obj_id]
    twin_posed = bool(same_class) and all(
        any(np.linalg.norm(c - centres[j]) <= 0.05 for j in twins) for c in same_class)
    if kind == 'none':
        cause = 'no region'
    elif own_class_dropped:
        cause = 'dropped'
    elif kind in ('with twin', 'with other', 'several', 'other'):
        cause = f'region {kind}'
    elif not own_class_fit:
        cause = ('named other (its class offered)' if offered else 'named other') if fits \
            else 'no fit'
    else:
        cause = 'pose off' if kind == 'alone' else f'pose off ({kind})'
    return {'scene': side.scene_id, 'im': side.im_id, 'part': k,
            'name': names.get(gt.obj_id, gt.obj_id), 'twins': len(twins),
            'twin_posed': twin_posed, 'view': view, 'px': counts[view], 'region': kind,
            'make_up': make_up, 'fits': ' | '.join(fits) or '-',
            'poses_of_class': ' '.join(where(c)[1] for c in same_class) or '-',
            'second_near': second, 'cause': cause}


def _load(parts: str) -> tuple[TemplateDatabase, LinearClassifier, dict]:
    if parts == 'T':
        return (TemplateDatabase.load(PACKAGED / 'templates.npz'),
                LinearClassifier.load(PACKAGED / 'classifier.npz'), {})
    folder = Path(parts)
    names = {p['id']: p['name'] for p in json.loads(
        (folder / 'manifest.json').read_text())['parts']}
    return (TemplateDatabase.load(folder / 'templates.npz'),
            LinearClassifier.load(folder / 'classifier.npz'), names)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('scenes', type=Path)
    ap.add_argument('parts')
    ap.add_argument('estimates', type=Path)
    ap.add_argument('--tsv', type=Path)
    ap.add_argument('--frames', type=int, nargs='*', help='only these frames (im ids)')
    ap.add_argument('--pipeline-param', action='append', metavar='NAME=VALUE',
                    help='a pipeline stage parameter, as tlessbot evaluate takes it')
    args = ap.parse_args()
    far = _far_parts(args.scenes, args.estimates)
    _hook()
    database, model, names = _load(args.parts)
    pipeline, rows = None, []
    for by_view, views in two_view_frames(args.scenes, args.frames):
        top, side = by_view[TOP], by_view[SIDE]
        if (side.scene_id, side.im_id) not in far:
            continue
        if pipeline is None:
            pipeline = _first_pipeline(by_view, classifier=model, templates=database,
                                       **stage_overrides(args.pipeline_param))
        record.clear()
        result = pipeline.process(views)
        for k in far[(side.scene_id, side.im_id)]:
            rows.append(_trace_part(k, side, top, views, result, names))
        print(f'frame {side.im_id}: {len(far[(side.scene_id, side.im_id)])} far',
              file=sys.stderr)
    keys = list(rows[0]) if rows else []
    lines = ['\t'.join(keys)] + ['\t'.join(str(r[k]) for k in keys) for r in rows]
    print('\n'.join(lines))
    if args.tsv:
        args.tsv.write_text('\n'.join(lines) + '\n')
    print('cause:', dict(Counter(r['cause'] for r in rows)), file=sys.stderr)
    print('region:', dict(Counter(r['region'] for r in rows)), file=sys.stderr)
    print('twin posed:', sum(r['twin_posed'] for r in rows), 'of', len(rows),
          '; second pose near:', sum(r['second_near'] for r in rows), file=sys.stderr)


if __name__ == '__main__':
    main()
