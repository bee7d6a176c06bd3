"""Where the localiser cuts one part into pieces: each part split in the fused side labels,
and which step of the side segmentation made the cut, in a minute a cell.

    python scripts/split_cuts_trace.py SCENES TEMPLATES [--frames 0 6 ...] [--tsv OUT.tsv]
        [--pipeline-param NAME=VALUE ...]

SCENES: a scenes folder of the bench (scored in ``test_side``); TEMPLATES: the templates the
cell is scored with (the parts' sizes). Runs ``PerceptionPipeline.localise`` only. A part
(at least 30 visible side pixels) is split where two instances each hold a sixth of it
(``false_box_causes.py``'s split, on the localiser's labels). Per split part:

* ``foreground``: the side foreground (before instance separation) holds the part in two
  blobs that each hold a sixth of it (a band the cues read as table);
* ``side_seg``: whether the side segmentation (before the fusion) splits it too, else the
  fusion did;
* ``whole_without``: the steps of the side view's instance separation that, each turned off
  alone, leave the part whole in the fused labels: ``depth`` (``depth_split_jump`` 0),
  ``colour`` (``colour_split_delta`` 0), ``lightness`` (``lightness_split_ratio`` 0),
  ``cores`` (the distance cores, ``split_min_core_px`` huge), ``all``
  (``split_touching`` false); and of the fusion's: ``table`` (``table_divides`` false),
  ``gap`` (``gap_table_floors`` 0);
* ``top_seg``: whether the top segmentation holds the part in two blobs (a sixth each);
* the pieces' pixels, their ``shared_border_ratio`` and whether each could be a whole part.
"""
from __future__ import annotations

import sys
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core import pipeline as pipeline_module
from tlessbot_ros.core.common import SIDE, TOP
from tlessbot_ros.core.localise.part_scale import holds_whole_part, shared_border_ratio
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.tools.support.eval_frames import two_view_frames

SIXTH = 1 / 6
ABLATIONS = {'depth': ['depth_split_jump=0'], 'colour': ['colour_split_delta=0'],
             'lightness': ['lightness_split_ratio=0'], 'cores': ['split_min_core_px=100000000'],
             'all': ['split_touching=false'], 'table': ['table_divides=false'],
             'gap': ['gap_table_floors=0']}
record: dict = {}
sys.path.insert(0, str(Path(__file__).resolve().parent))
from pile_regions import localiser_arguments, localiser_pipeline  # noqa: E402  (beside this one)


def _hook() -> None:
    segment = pipeline_module.segment

    def seg(*args, split_by_depth, **kw):
        out = segment(*args, split_by_depth=split_by_depth, **kw)
        record['side' if split_by_depth else 'top'] = out
        return out

    pipeline_module.segment = seg


def pieces_of(labels: np.ndarray, mask: np.ndarray) -> list[tuple[int, int]]:
    """(label, pixels on the part) of the instances holding a sixth of the part, largest
    first."""
    values, counts = np.unique(labels[mask], return_counts=True)
    total = int(mask.sum())
    out = [(int(v), int(c)) for v, c in zip(values, counts) if v and c >= SIXTH * total]
    return sorted(out, key=lambda vc: -vc[1])


def is_split(labels: np.ndarray, mask: np.ndarray) -> bool:
    return len(pieces_of(labels, mask)) >= 2


def _top_seg(labels: np.ndarray, mask: np.ndarray | None) -> str:
    if mask is None or mask.sum() < 30:
        return 'unseen'
    return 'split' if is_split(labels, mask) else 'one'


def main() -> None:
    args = localiser_arguments(__doc__.split('\n')[0]).parse_args()
    _hook()
    database = TemplateDatabase.load(args.templates)
    pipelines: dict[str, PerceptionPipeline] = {}
    rows = []
    for by_view, views in two_view_frames(args.scenes, args.frames):
        side, top = by_view[SIDE], by_view[TOP]
        if not pipelines:
            pipelines = {name: localiser_pipeline(by_view, database, args.pipeline_param + extra)
                         for name, extra in [('base', [])] + list(ABLATIONS.items())}
        record.clear()
        fused = pipelines['base'].localise(views).labels[SIDE]
        seg = record['side']
        whole_parts = seg.whole_parts
        _, fg = cv2.connectedComponents(seg.foreground.view(np.uint8), connectivity=8)
        split = [(k, g) for k, g in enumerate(side.gt)
                 if g.mask is not None and g.mask.sum() >= 30 and is_split(fused, g.mask)]
        if not split:
            continue
        ablated = {}
        for name in ABLATIONS:
            ablated[name] = pipelines[name].localise(views).labels[SIDE]
        for k, g in split:
            held = pieces_of(fused, g.mask)
            a, b = (fused == held[0][0]), (fused == held[1][0])
            row = {'im': side.im_id, 'part': k, 'obj': g.obj_id, 'px': int(g.mask.sum()),
                   'pieces': ' '.join(f'{int((fused == v).sum())}/{c}' for v, c in held),
                   'foreground': 'split' if is_split(fg, g.mask) else 'one',
                   'side_seg': 'split' if is_split(seg.labels, g.mask) else 'one',
                   'top_seg': _top_seg(record['top'].labels, top.gt[k].mask),
                   'border': round(shared_border_ratio(a, b), 2),
                   'each_whole': int(holds_whole_part(a, whole_parts)
                                     and holds_whole_part(b, whole_parts)),
                   'whole_without': ','.join(n for n, lab in ablated.items()
                                             if not is_split(lab, g.mask)) or '-'}
            rows.append(row)
            print('\t'.join(f'{key}={v}' for key, v in row.items()), file=sys.stderr)
    if args.tsv:
        keys = list(rows[0]) if rows else ['im']
        args.tsv.write_text('\n'.join(['\t'.join(keys)] + [
            '\t'.join(str(r[k]) for k in keys) for r in rows]) + '\n')


if __name__ == '__main__':
    main()
