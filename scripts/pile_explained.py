"""How much of its region each first fit explains, against how many parts the region holds:
is a region that no single part explains a merge?

    python scripts/pile_explained.py SCENES PARTS [--frames 0 6 ...] [--tsv OUT.tsv]
        [--pipeline-param NAME=VALUE ...]

SCENES, PARTS as ``pile_far_parts.py`` takes them. The pipeline runs as ``tlessbot evaluate``
does; each region's first fit (before any division) is recorded with the share of the
region's depth points it explains (inside its outline, within ``verify_inlier_m`` of its
surface, :func:`~tlessbot_ros.core.two_parts.explained`; and within twice that), and the
ground-truth parts over the region (in the fitted view: each part whose visible mask holds at
least a fifth of the region's pixels). Printed: the first fit's explained share (3 mm) of the
regions over one part and over two or more, and how many lie below 0.5 ... 0.8.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from tlessbot_ros.core import pipeline as pipeline_module
from tlessbot_ros.core.part_fit import pose_stage
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.recognise import UNKNOWN_ID
from tlessbot_ros.core.two_parts import explained
from tlessbot_ros.tools.support.eval_frames import _first_pipeline, two_view_frames
from tlessbot_ros.tools.support.overrides import stage_overrides

sys.path.insert(0, str(Path(__file__).resolve().parent))
from pile_far_parts import _load  # noqa: E402

SHARE = 0.2
record: dict = {}


def _hook() -> None:
    fuse, fit_part = pipeline_module.fuse_views, PerceptionPipeline.fit_part

    def fused(*args, **kw):
        out = fuse(*args, **kw)
        record['fused'] = {k: v.copy() for k, v in out.labels.items()}
        return out

    def fitted(self, job):
        fit_part(self, job)
        seen = record.setdefault('seen', set())
        if id(job) in seen:
            return
        seen.add(id(job))
        d = job.detection
        row = {'view': d.view, 'inst': d.instance_id, 'obj': d.obj_id,
               'n_points': len(job.points), 'expl3': np.nan, 'expl6': np.nan, 'T': None}
        if d.pose is not None and d.obj_id != UNKNOWN_ID and len(job.points):
            est = pose_stage(self.pose_estimator)
            obj = est.database[d.obj_id]
            pts = np.asarray(job.points, np.float64)
            tol = self.fit_params.verify_inlier_m
            T = d.pose.T_camera_object
            row['expl3'] = float(explained(pts, obj, T, est.refiner, tol).mean())
            row['expl6'] = float(explained(pts, obj, T, est.refiner, 2 * tol).mean())
            row['T'] = T.copy()
        record.setdefault('fits', []).append(row)

    pipeline_module.fuse_views = fused
    PerceptionPipeline.fit_part = fitted   # type: ignore[method-assign]


def _parts_over(region: np.ndarray, image) -> tuple[int, float, list[int]]:
    """(parts holding >= SHARE of the region, the largest share, their indices)."""
    total = max(int(region.sum()), 1)
    shares = [(float((region & g.mask).sum()) / total, k) for k, g in enumerate(image.gt)
              if g.mask is not None]
    over = [k for s, k in shares if s >= SHARE]
    return len(over), max((s for s, _ in shares), default=0.0), over


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('scenes', type=Path)
    ap.add_argument('parts')
    ap.add_argument('--tsv', type=Path)
    ap.add_argument('--frames', type=int, nargs='*')
    ap.add_argument('--pipeline-param', action='append', metavar='NAME=VALUE')
    args = ap.parse_args()
    _hook()
    database, model, names = _load(args.parts)
    pipeline, rows = None, []
    for by_view, views in two_view_frames(args.scenes, args.frames):
        if pipeline is None:
            pipeline = _first_pipeline(by_view, classifier=model, templates=database,
                                       **stage_overrides(args.pipeline_param))
        record.clear()
        pipeline.process(views)
        for row in record.get('fits', []):
            labels = record['fused'].get(row['view'])
            if labels is None:
                continue
            region = labels == row['inst']
            if not region.any():
                continue   # a piece divided off, not a fused region
            image = by_view[row['view']]
            n, top_share, over = _parts_over(region, image)
            near = np.inf
            if row['T'] is not None:
                c = row['T'][:3, 3]
                near = min((np.linalg.norm(c - g.T_camera_object[:3, 3]) for g in image.gt
                            if g.obj_id == row['obj']), default=np.inf)
            rows.append({'im': image.im_id, 'view': row['view'], 'inst': row['inst'],
                         'obj': names.get(row['obj'], row['obj']), 'points': row['n_points'],
                         'parts': n, 'top_share': round(top_share, 2),
                         'expl3': round(row['expl3'], 3), 'expl6': round(row['expl6'], 3),
                         'own_class_mm': round(1e3 * near, 0)})
        print(f'frame {by_view[next(iter(by_view))].im_id}: {len(rows)} fits', file=sys.stderr)
    keys = list(rows[0]) if rows else []
    lines = ['\t'.join(keys)] + ['\t'.join(str(r[k]) for k in keys) for r in rows]
    if args.tsv:
        args.tsv.write_text('\n'.join(lines) + '\n')
    firsts, seen = [], set()   # a region refitted (joined, divided) counts once: its first fit
    for r in rows:
        if (r['im'], r['view'], r['inst']) not in seen and np.isfinite(r['expl3']):
            seen.add((r['im'], r['view'], r['inst']))
            firsts.append(r)
    for label, many in (('one part', False), ('two or more', True)):
        e = np.array([r['expl3'] for r in firsts if r['parts'] > 0 and (r['parts'] > 1) == many])
        if len(e):
            q = np.percentile(e, [10, 50, 90])
            below = ' '.join(f'<{t}: {np.count_nonzero(e < t)}' for t in (0.5, 0.6, 0.7, 0.8))
            print(f'{label}: {len(e)} regions, explained (3 mm) p10/50/90 '
                  + ' '.join(f'{x:.2f}' for x in q) + f'; {below}', file=sys.stderr)


if __name__ == '__main__':
    main()
