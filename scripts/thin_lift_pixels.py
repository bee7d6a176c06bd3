"""Which pixels the thin lift (``segmentation.thin_lift_height_m``) takes from the depth's veto,
without its resolved rule (``thin_lift_resolved_k: 0``, main before it) and with it, by whose
ground-truth mask they lie in (a part's, or none: a hole, the table around a part), with their
height below the lifted blob's median in the table's noise deviations.
docs/bench/thin-lift-holes.md.

    python scripts/thin_lift_pixels.py SCENES TEMPLATES [FRAMES]   # FRAMES: 0,5,7
"""
from __future__ import annotations

import sys
from collections import defaultdict
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from tlessbot_ros.core.localise import segmentation as segmentation_module
from tlessbot_ros.core.pipeline import PerceptionPipeline
from tlessbot_ros.core.pose import TemplateDatabase

sys.path.insert(0, str(Path(__file__).parent))
from table_false_parts_cues import segmentations, two_view_frames  # noqa: E402


def lifted_records(pipeline: PerceptionPipeline, views: dict) -> list[tuple]:
    """(candidate, height, table, lifted without the resolved rule, lifted, sigma) of each
    call of the lift while ``pipeline`` localises ``views``, in call order."""
    calls: list[tuple] = []
    original = segmentation_module.thin_lift

    def spy(candidate, height_m, table, params, **kw):
        lifted, regions = original(candidate, height_m, table, params, **kw)
        every = original(candidate, height_m, table,
                         replace(params, thin_lift_resolved_k=0.0), **kw)[0]
        sigma = kw.get('noise_m', 0.0)
        calls.append((candidate.copy(), height_m, table.copy(), every, lifted, sigma))
        return lifted, regions
    segmentation_module.thin_lift = spy
    try:
        segmentations(pipeline, views)
    finally:
        segmentation_module.thin_lift = original
    return calls


def truth_ids(image, shape: tuple[int, int]) -> np.ndarray:
    """(h, w) int: the obj id of the ground-truth visible mask at each pixel (0: none)."""
    ids = np.zeros(shape, np.int32)
    for part in image.gt:
        if part.mask is not None:
            small = cv2.resize(part.mask.view(np.uint8), (shape[1], shape[0]),
                               interpolation=cv2.INTER_NEAREST) > 0
            ids[small] = part.obj_id
    return ids


def _report_blobs(index: int, name: str, ids: np.ndarray, candidate: np.ndarray,
                  height: np.ndarray, table: np.ndarray, every: np.ndarray,
                  lifted: np.ndarray, sigma: float, depths: dict) -> None:
    """One line per lifted blob of a view (without the rule), its freed pixels into
    ``depths``."""
    freed_rule = table & lifted
    count, labels = cv2.connectedComponents(candidate.view(np.uint8), connectivity=8)
    for k in range(1, count):
        blob = labels == k
        freed = blob & every & table
        if not freed.any():
            continue
        valid = np.sort(height[blob][np.isfinite(height[blob])])
        if not valid.size:
            continue
        median = float(valid[(valid.size - 1) // 2])   # the lower median, as thin.py's
        owners = np.bincount(ids[blob & ~table], minlength=1)
        owner = int(np.argmax(owners[1:]) + 1) if owners[1:].any() else 0
        z = (median - height[freed]) / max(sigma, 1e-4)
        for obj, zz, kept in zip(ids[freed], z, freed_rule[freed]):
            depths[(name, int(obj))].append((float(zz), bool(kept)))
        print(f'frame {index} {name} blob of obj {owner}: {blob.sum()} px, median '
              f'{1000 * median:.1f} mm, sigma {1000 * sigma:.2f} mm, freed {freed.sum()} '
              f'(in no mask {np.sum(ids[freed] == 0)}, own {np.sum(ids[freed] == owner)}; '
              f'with the rule {np.sum(freed_rule[freed])}), z of freed '
              f'{np.round(np.sort(z), 1).tolist()[:12]}')


def main(argv: list[str]) -> int:
    scenes, templates = argv[:2]
    frames = {int(a) for a in argv[2].split(',')} if len(argv) > 2 else None
    pipeline = None
    # (view, obj id or 0) -> (median - height) / sigma of each pixel freed without the rule,
    # and whether the rule frees it too
    depths: dict[tuple[str, int], list[tuple[float, bool]]] = defaultdict(list)
    for index, (images, views, rig) in enumerate(two_view_frames(scenes)):
        if frames is not None and index > max(frames):
            break
        if pipeline is None:
            pipeline = PerceptionPipeline(rig=rig, templates=TemplateDatabase.load(templates))
            # the views one after the other (top first), so the calls come in that order
            pipeline.localise_params = replace(pipeline.localise_params, parallel_views=False)
        if frames is not None and index not in frames:   # the table tracked as evaluate does
            for name, view in views.items():
                pipeline.table_frame(name, view)
            continue
        calls = lifted_records(pipeline, views)
        for name, (cand, height, table, every, lifted, sigma) in zip(('top', 'side'), calls):
            ids = truth_ids(images[name], cand.shape)
            _report_blobs(index, name, ids, cand, height, table, every, lifted, sigma,
                          depths)
    print('view\tobj\tfreed px (main)\tfreed px (rule)\tz quantiles 0.1-0.9 (without the rule)')
    for (name, obj), rows in sorted(depths.items()):
        z = np.array([r[0] for r in rows])
        kept = sum(r[1] for r in rows)
        q = np.quantile(z, [0.1, 0.25, 0.5, 0.75, 0.9])
        print(f'{name}\t{obj}\t{len(z)}\t{kept}\t{np.round(q, 1).tolist()}')
    return 0


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
