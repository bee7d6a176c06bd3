"""Every pair of parts found in one region, where the localiser joined them and why the pose
stage's division (core/two_parts.py) did not part them.

    python scripts/merged_parts_trace.py SCENES PARTS [--frames 0 6 ...] [--tsv OUT.tsv]

SCENES: a scenes folder of the bench (scored in ``test_side``); PARTS: its parts folder
(models/, classifier.npz, templates.npz). The pipeline runs as ``tlessbot evaluate`` does, with
its stages recorded: the side and top segmentations, the fusion's labels, and each call of
``two_parts.split_off`` with the first test that stopped it. One row per ground-truth part
whose largest side-view instance after the fusion also holds >= 20 % of another part
(``merged``): where the pair is one instance (side segmentation, top segmentation, fusion),
what ``split_off`` did on that instance (``divided`` or the test that stopped it), whether the
pair is still one region at the end, whether the part got a pose of its class within 5 cm,
and what the side view shows between the two (gap in px between their ground-truth masks,
CIE-Lab distance of their median colours, their median heights over the table in mm).
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from tlessbot_ros.core import pipeline as pipeline_module
from tlessbot_ros.core import two_parts
from tlessbot_ros.core.common import SIDE, TOP, CameraMount, Rig
from tlessbot_ros.core.localise import rgb_to_lab
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.io.bop import read_split

MERGED_SHARE = 0.2
record: dict = {}


def _hook() -> None:
    """Record the stages (module attributes replaced; the pipeline looks them up there)."""
    segment, fuse = pipeline_module.segment, pipeline_module.fuse_views

    def seg(*args, split_by_depth, **kw):
        out = segment(*args, split_by_depth=split_by_depth, **kw)
        record[SIDE if split_by_depth else TOP] = out.labels.copy()
        return out

    def fused(*args, **kw):
        out = fuse(*args, **kw)
        record['fused'] = {k: v.copy() for k, v in out.labels.items()}
        record['pred'] = None if out.predicted_side is None else out.predicted_side.copy()
        return out

    pipeline_module.segment, pipeline_module.fuse_views = seg, fused
    for name in ('piece_in_views', 'touches', 'divided_job', 'fits_alone', 'same_place',
                 'apart', 'seen_share', 'reassigned'):
        _wrap(name)
    split_off = two_parts.split_off

    def traced(pipeline, job, *args, **kw):
        steps: list = []
        record['steps'] = steps
        before = job.detection.obj_id
        out = split_off(pipeline, job, *args, **kw)
        record.setdefault('calls', []).append(
            (job.detection.instance_id, before, _reason(steps, out is not None), out))
        return out

    two_parts.split_off = traced


def _wrap(name: str) -> None:
    inner = getattr(two_parts, name)

    def wrapped(*args, **kw):
        out = inner(*args, **kw)
        if 'steps' in record:
            value = out
            if name == 'piece_in_views':
                value = bool(out)
            elif name == 'divided_job':
                value = None if out is None else out.detection.obj_id
            elif name == 'seen_share':
                value = round(float(out), 2)
            elif name == 'reassigned':
                value = True
            record['steps'].append((name, value))
        return out

    setattr(two_parts, name, wrapped)


def _reason(steps: list, kept: bool) -> str:
    """The first test that stopped a ``split_off`` call (see the module)."""
    if kept:
        return 'divided'
    seen = dict()
    order = []
    for name, value in steps:
        order.append(name)
        seen.setdefault(name, []).append(value)
    if 'piece_in_views' not in seen:
        return 'not tried (no flat part known)'
    if not seen['piece_in_views'][0]:
        return 'no piece (fit explains region)'
    if seen.get('touches', [False])[0]:
        return 'touches a piece'
    jobs = seen.get('divided_job', [])
    alone = seen.get('fits_alone', [])
    if not jobs or jobs[0] is None:
        return 'piece: no class / few points / not raised'
    if not alone or not alone[0]:
        return f'piece ({jobs[0]}) not a part (fits_alone)'
    if seen.get('same_place', [False])[-1] and len(jobs) == 1:
        return f'piece ({jobs[0]}) at another fit'
    if len(jobs) < 2 or jobs[1] is None:
        return 'rest: no class / few points'
    if len(alone) < 2 or not alone[1]:
        return f'rest ({jobs[1]}) not a part (fits_alone)'
    if not seen.get('apart', [True])[0]:
        return f'not apart ({jobs[0]}, {jobs[1]})'
    if 'reassigned' not in seen:
        return f'neither flat ({jobs[0]}, {jobs[1]})'
    return f'seen_share {seen.get("seen_share", ["?"])[-1]} ({jobs[0]}, {jobs[1]})'


def _majority(labels: np.ndarray, mask: np.ndarray) -> int:
    values = labels[mask]
    values = values[values > 0]
    return int(np.bincount(values).argmax()) if values.size else 0


def _same(labels: np.ndarray, a: np.ndarray | None, b: np.ndarray | None) -> str:
    """'same' / 'apart' instance of ``labels`` for two masks, or which one it lacks."""
    ids = [_majority(labels, m) if m is not None and m.any() else 0 for m in (a, b)]
    if not all(ids):
        return 'none' if not any(ids) else 'part none' if not ids[0] else 'with none'
    return 'same' if ids[0] == ids[1] else 'apart'


def _gap_px(a: np.ndarray, b: np.ndarray) -> float:
    import cv2
    dist = cv2.distanceTransform((~a).astype(np.uint8), cv2.DIST_L2, 3)
    return float(dist[b].min()) if b.any() else np.inf


def _gap_lit(a: np.ndarray, b: np.ndarray, parts: np.ndarray,
             fused: np.ndarray) -> str:
    """The share of the gap's pixels (within 5 px of both masks, on no part) within 2 colour
    floors (16 L, 12 a / b) of the nearest pixel on no part and in no region, and their count."""
    import cv2
    from scipy import ndimage
    near = [cv2.distanceTransform((~m).astype(np.uint8), cv2.DIST_L2, 3) <= 5 for m in (a, b)]
    gap = near[0] & near[1] & ~parts
    if not gap.any():
        return '-'
    off = cv2.erode((~parts & (fused == 0)).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    if not off.any():
        return '-'
    blurred = rgb_to_lab(cv2.blur(record['rgb'], (3, 3)))
    iy, ix = ndimage.distance_transform_edt(~off, return_distances=False, return_indices=True)
    lit = (np.abs(blurred - blurred[iy, ix]) <= np.array([16.0, 12.0, 12.0])).all(axis=2)
    return f'{lit[gap].mean():.2f}/{int(gap.sum())}'


def _found(result, views, side, k: int) -> bool:
    gt = side.gt[k]
    centre = (side.T_world_camera @ gt.T_camera_object)[:3, 3]
    for d in result.detections:
        if d.obj_id != gt.obj_id or d.pose is None:
            continue
        T = views[d.view].T_world_camera @ d.pose.T_camera_object
        if np.linalg.norm(T[:3, 3] - centre) <= 0.05:
            return True
    return False


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('scenes', type=Path)
    ap.add_argument('parts', type=Path)
    ap.add_argument('--frames', type=int, nargs='*')
    ap.add_argument('--tsv', type=Path)
    ap.add_argument('--pipeline-param', action='append', metavar='NAME=VALUE',
                    help='a pipeline stage parameter, as tlessbot evaluate takes it')
    args = ap.parse_args()
    _hook()
    database = TemplateDatabase.load(args.parts / 'templates.npz')
    model = LinearClassifier.load(args.parts / 'classifier.npz')
    names = {p['id']: p['name'] for p in json.loads(
        (args.parts / 'manifest.json').read_text())['parts']}
    pipeline = None
    rows = []
    readers = [read_split(args.scenes, f'test_{v}') for v in (TOP, SIDE)]
    for top, side in zip(*readers):
        if args.frames is not None and side.im_id not in args.frames:
            continue
        by_view = {TOP: top, SIDE: side}
        if pipeline is None:
            rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                       for v, im in by_view.items()})
            from tlessbot_ros.tools.support.overrides import stage_overrides
            pipeline = PerceptionPipeline(rig=rig, classifier=model, templates=database,
                                          **stage_overrides(args.pipeline_param))
        record.clear()
        views = {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera)
                 for v, im in by_view.items()}
        result = pipeline.process(views)
        fused, final = record['fused'][SIDE], result.labels[SIDE]
        calls: dict[int, list] = {}
        for inst, before, reason, _ in record.get('calls', []):
            calls.setdefault(inst, []).append(f'{names.get(before, before)}: {reason}')
        lab = rgb_to_lab(side.rgb)
        record['rgb'] = side.rgb
        parts = np.logical_or.reduce([g.mask for g in side.gt if g.mask is not None]
                                     + [np.zeros(side.rgb.shape[:2], bool)])
        T_table = pipeline.table_frames[SIDE].T_world_camera if SIDE in pipeline.table_frames \
            else None
        for k, gt in enumerate(side.gt):
            mask = gt.mask
            if mask is None or mask.sum() < 30:
                continue
            inst = _majority(fused, mask)
            if not inst:
                continue
            region = fused == inst
            for j, other in enumerate(side.gt):
                if j == k or other.mask is None or \
                        (region & other.mask).sum() < MERGED_SHARE * region.sum():
                    continue
                if _majority(fused, other.mask) == inst and j < k:
                    continue   # the pair once
                o_mask = other.mask
                top_k, top_j = top.gt[k].mask, top.gt[j].mask
                same_top = _same(record[TOP], top_k, top_j)
                same_top_fused = _same(record['fused'][TOP], top_k, top_j)
                heights = []
                if T_table is not None and side.depth_m is not None:
                    from tlessbot_ros.core.common import depth_to_points, transform_points
                    for m in (mask, o_mask):
                        pts, _ = depth_to_points(side.depth_m, side.intrinsics.K, mask=m)
                        heights.append(1e3 * float(np.median(transform_points(
                            T_table, pts.astype(np.float64))[:, 2])) if len(pts) else np.nan)
                dE = float(np.linalg.norm(np.median(lab[mask], 0) - np.median(lab[o_mask], 0)))
                flat = pipeline.flat_ids
                rows.append({
                    'scene': side.scene_id, 'im': side.im_id,
                    'part': names[gt.obj_id], 'with': names[other.obj_id],
                    'flat': f'{"F" if gt.obj_id in flat else "t"}'
                            f'{"F" if other.obj_id in flat else "t"}',
                    'side_seg': _same(record[SIDE], mask, o_mask),
                    'top_seg': same_top, 'top_fused': same_top_fused,
                    'top_pred': '-' if record['pred'] is None else
                    _same(record['pred'], mask, o_mask),
                    'gap_lit': _gap_lit(mask, o_mask, parts, fused),
                    'split': ' | '.join(calls.get(inst, ['no split_off call'])),
                    'still': _majority(final, mask) == _majority(final, o_mask),
                    'found': _found(result, views, side, k),
                    'found_with': _found(result, views, side, j),
                    'gap_px': round(_gap_px(mask, o_mask), 1), 'dE': round(dE, 1),
                    'h_mm': '/'.join(f'{h:.1f}' for h in heights)})
        print(f'frame {side.im_id}: {sum(r["im"] == side.im_id for r in rows)} pairs',
              file=sys.stderr)
    keys = list(rows[0]) if rows else []
    lines = ['\t'.join(keys)] + ['\t'.join(str(r[k]) for k in keys) for r in rows]
    print('\n'.join(lines))
    if args.tsv:
        args.tsv.write_text('\n'.join(lines) + '\n')
    print('where joined:', Counter(
        'side seg' if r['side_seg'] == 'same' else 'fusion' for r in rows), file=sys.stderr)
    print('split_off:', Counter(r['split'].split(': ', 1)[-1].split(' (')[0] for r in rows),
          file=sys.stderr)


if __name__ == '__main__':
    main()
