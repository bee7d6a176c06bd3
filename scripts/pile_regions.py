"""The localiser alone on a scenes folder: each ground-truth part's side-view region by cause
(whole, merged, split, missed) and the regions on no part, in a minute a cell.

    python scripts/pile_regions.py SCENES TEMPLATES [--pipeline-param NAME=VALUE ...]
        [--frames 0 6 ...] [--tsv OUT.tsv] [--against NAME=VALUE ...]

SCENES: a scenes folder of the bench (scored in ``test_side``); TEMPLATES: the templates the
cell is scored with (they give the parts' sizes, as ``tlessbot evaluate`` has them). Runs
``PerceptionPipeline.localise`` only (no classifier, no pose) and reads the fused side labels.
Each part with at least 30 visible side pixels is

* ``missed``: no instance holds a fifth of its pixels;
* ``merged``: the instance holding most of it also holds a fifth of another part's pixels
  (the other part is named, and whether the side and top segmentations, before the fusion,
  had the two apart);
* ``split``: no instance holds half of it (several do);
* ``whole`` otherwise.

A region is on no part when three quarters of it lie on no part's visible mask. The totals
are printed to stderr, one row per part to ``--tsv``. With ``--against`` a second pipeline
(the same overrides, then these) localises every frame too: its totals, and the frames whose
fused labels (either view) differ between the two; the pose stage gives the same estimates on
the others.
"""
from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from tlessbot_ros.core import pipeline as pipeline_module
from tlessbot_ros.core.common import SIDE, TOP, CameraMount, Rig
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.tools.support.eval_frames import two_view_frames
from tlessbot_ros.tools.support.overrides import stage_overrides

SHARE = 0.2
record: dict = {}


def _hook() -> None:
    segment = pipeline_module.segment

    def seg(*args, split_by_depth, **kw):
        out = segment(*args, split_by_depth=split_by_depth, **kw)
        record[SIDE if split_by_depth else TOP] = out.labels.copy()
        return out

    pipeline_module.segment = seg


def _majority(labels: np.ndarray, mask: np.ndarray | None) -> int:
    if mask is None:
        return 0
    values = labels[mask]
    values = values[values > 0]
    return int(np.bincount(values).argmax()) if values.size else 0


def _apart(labels: np.ndarray, a: np.ndarray | None, b: np.ndarray | None) -> str:
    ia, ib = _majority(labels, a), _majority(labels, b)
    if not ia or not ib:
        return 'none'
    return 'same' if ia == ib else 'apart'


def parts_by_cause(fused_side: np.ndarray, side_seg: np.ndarray, top_seg: np.ndarray,
                   side_masks: list, top_masks: list) -> tuple[list[dict], int, int]:
    """(one row per part, regions on no part, regions) of one frame (see the module)."""
    rows = []
    ids, counts = np.unique(fused_side[fused_side > 0], return_counts=True)
    size = dict(zip(ids.tolist(), counts.tolist()))
    for k, mask in enumerate(side_masks):
        if mask is None or mask.sum() < 30:
            continue
        values, shares = np.unique(fused_side[mask], return_counts=True)
        held = {int(v): c / mask.sum() for v, c in zip(values, shares) if v}
        best = max(held, key=held.get) if held else 0
        row = {'part': k, 'px': int(mask.sum()), 'share': round(held.get(best, 0.0), 2),
               'with': '', 'side_seg': '', 'top_seg': ''}
        if not held or held[best] < SHARE:
            row['cause'] = 'missed'
        else:
            region = fused_side == best
            others = [j for j, m in enumerate(side_masks) if j != k and m is not None
                      and (region & m).sum() >= SHARE * m.sum()]
            if others:
                j = max(others, key=lambda j: int((region & side_masks[j]).sum()))
                row.update(cause='merged', With=j)
                row['with'] = j
                row['side_seg'] = _apart(side_seg, mask, side_masks[j])
                row['top_seg'] = _apart(top_seg, top_masks[k], top_masks[j])
            elif held[best] < 0.5:
                row['cause'] = 'split'
            else:
                row['cause'] = 'whole'
        rows.append(row)
    on_parts = np.logical_or.reduce([m for m in side_masks if m is not None]
                                    + [np.zeros(fused_side.shape, bool)])
    false = sum(1 for i in size if (on_parts & (fused_side == i)).sum() < 0.25 * size[i])
    return rows, false, len(size)


def localiser_pipeline(by_view: dict, database: TemplateDatabase, overrides: list[str]
                       ) -> PerceptionPipeline:
    rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera) for v, im in by_view.items()})
    return PerceptionPipeline(rig=rig, part_extents_m=database.extents_m(),
                              **stage_overrides(overrides))


def _totals(name: str, rows: list[dict], false: int, regions: int) -> str:
    counts = Counter(r['cause'] for r in rows)
    merged = Counter(f'{r["side_seg"]}/{r["top_seg"]}' for r in rows if r['cause'] == 'merged')
    return (f'{name}: parts {len(rows)} ' +
            ' '.join(f'{c} {counts[c]}' for c in ('whole', 'merged', 'split', 'missed')) +
            f'; regions {regions}, on no part {false}; merged (side seg/top seg) {dict(merged)}')


def localiser_arguments(description: str) -> argparse.ArgumentParser:
    """The arguments of a script that localises a scenes folder: SCENES TEMPLATES
    [--frames] [--tsv] [--pipeline-param]."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument('scenes', type=Path)
    ap.add_argument('templates', type=Path)
    ap.add_argument('--frames', type=int, nargs='*')
    ap.add_argument('--tsv', type=Path)
    ap.add_argument('--pipeline-param', action='append', default=[], metavar='NAME=VALUE')
    return ap


def main() -> None:
    ap = localiser_arguments(__doc__.split('\n')[0])
    ap.add_argument('--against', action='append', default=[], metavar='NAME=VALUE')
    args = ap.parse_args()
    _hook()
    database = TemplateDatabase.load(args.templates)
    settings = [args.pipeline_param] + ([args.pipeline_param + args.against]
                                        if args.against else [])
    pipelines: list[PerceptionPipeline] = []
    rows: list[list[dict]] = [[] for _ in settings]
    false, regions = [0] * len(settings), [0] * len(settings)
    differ = []
    for by_view, views in two_view_frames(args.scenes, args.frames):
        top, side = by_view[TOP], by_view[SIDE]
        pipelines = pipelines or [localiser_pipeline(by_view, database, o) for o in settings]
        labels = []
        for n, pipeline in enumerate(pipelines):
            record.clear()
            fused = pipeline.localise(views)
            labels.append(fused.labels)
            got, f, count = parts_by_cause(fused.labels[SIDE], record[SIDE], record[TOP],
                                           [g.mask for g in side.gt], [g.mask for g in top.gt])
            for r in got:
                r['im'] = side.im_id
                r['obj'] = side.gt[r['part']].obj_id
            rows[n] += got
            false[n] += f
            regions[n] += count
        if len(labels) > 1 and any(not np.array_equal(labels[0][v], labels[1][v])
                                   for v in labels[0]):
            differ.append(side.im_id)
    name = f'{args.scenes.name}'
    print(_totals(name, rows[0], false[0], regions[0]), file=sys.stderr)
    if len(settings) > 1:
        print(_totals(f'{name} against', rows[1], false[1], regions[1]), file=sys.stderr)
        print(f'{name}: frames that differ {differ}', file=sys.stderr)
    if args.tsv:
        keys = ['im', 'part', 'obj', 'px', 'cause', 'share', 'with', 'side_seg', 'top_seg']
        args.tsv.write_text('\n'.join(['\t'.join(keys)] + [
            '\t'.join(str(r.get(k, '')) for k in keys) for r in rows[-1]]) + '\n')


if __name__ == '__main__':
    main()
