"""Which pixels the thin lift's colour regions (``segmentation.thin_lift_colour_floors``) take
from the depth's veto beyond the blob rule, per frame and view, by whose ground-truth mask
they lie in (0: none, the table). docs/bench/thin-lift-colour-regions.md.

    python scripts/thin_lift_regions.py SCENES TEMPLATES [--pipeline-param NAME=VALUE ...]

Localises every frame as ``evaluate`` does (the table tracked over the frames, the views one
after the other); the overrides go to the pipeline (set ``thin_lift_colour_floors=1`` where
the default is off).
"""
from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from tlessbot_ros.core.localise import segmentation as segmentation_module
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.tools.support.overrides import stage_overrides

sys.path.insert(0, str(Path(__file__).parent))
from table_false_parts_cues import segmentations, two_view_frames  # noqa: E402
from thin_lift_pixels import truth_ids  # noqa: E402


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('scenes')
    ap.add_argument('templates')
    ap.add_argument('--pipeline-param', action='append', default=[], metavar='NAME=VALUE')
    args = ap.parse_args(argv)
    original = segmentation_module.thin_lift
    freed: list[tuple[np.ndarray, np.ndarray]] = []

    def spy(candidate, height_m, table, params, **kw):
        lifted, regions = original(candidate, height_m, table, params, **kw)
        blob_rule = original(candidate, height_m, table, params,
                             noise_m=kw.get('noise_m', 0.0))[0]
        freed.append((lifted & ~blob_rule & table, candidate))   # table before the lift
        return lifted, regions

    pipeline = None
    totals: dict[int, int] = {}
    for index, (images, views, rig) in enumerate(two_view_frames(args.scenes)):
        if pipeline is None:
            pipeline = PerceptionPipeline(rig=rig, templates=TemplateDatabase.load(args.templates),
                                          **stage_overrides(args.pipeline_param))
            pipeline.localise_params = replace(pipeline.localise_params, parallel_views=False)
        freed.clear()
        segmentation_module.thin_lift = spy
        try:
            segmentations(pipeline, views)
        finally:
            segmentation_module.thin_lift = original
        for name, (pixels, candidate) in zip(('top', 'side'), freed):
            if not pixels.any():
                continue
            ids = np.bincount(truth_ids(images[name], candidate.shape)[pixels])
            by_id = {k: int(n) for k, n in enumerate(ids) if n}
            for k, n in by_id.items():
                totals[k] = totals.get(k, 0) + n
            print(f'frame {index} {name}: {int(pixels.sum())} pixels freed, by obj id {by_id}')
    print(f'all frames, by obj id (0: no part): {dict(sorted(totals.items()))}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
