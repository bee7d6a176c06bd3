"""Every part with no pose of its class within 5 cm ("none" of own_parts_why.py), by cause.

    python scripts/own_parts_none.py SCENES MODELS ESTIMATES_CSV [--manifest PARTS/manifest.json]
        [--rerun --classifier C.npz --templates T.npz] [--named-cm 1.5]

From the estimates alone, each "none" part is

* ``missed``: no estimate of any class within 5 cm of its centre;
* ``named``: an estimate of another class within ``--named-cm`` (the pair, and whether the
  manifest lists the two as look-alikes);
* ``merged``: the nearest estimate within 5 cm is the pose of a neighbour (its class, nearer to
  the neighbour's centre than to this part's) whose side-view mask touches this part's;
* ``other``: anything else (an estimate of another class 1.5-5 cm off, not a neighbour's).

With ``--rerun`` the pipeline runs again (as ``tlessbot evaluate``) on the frames that hold a
"none" part and says, for each, which instance of the side view holds it (none: the localiser
lost it; one that also holds >= 20 % of another part: merged), the classifier's rank of the
right class on that instance (1 = first), the classes the pose stage fitted and the class it
kept. A rerun is a new run: Open3D's RANSAC moves about one part a cell between runs.
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter, defaultdict
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from own_parts_why import _estimates  # noqa: E402

NEAR_M = 0.05


def _masks(scene: Path, im: int, count: int) -> list[np.ndarray | None]:
    out: list[np.ndarray | None] = []
    for k in range(count):
        path = scene / 'mask_visib' / f'{im:06d}_{k:06d}.png'
        out.append(cv2.imread(str(path), cv2.IMREAD_GRAYSCALE) > 0 if path.exists() else None)
    return out


def _touching(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return False
    grown = cv2.dilate(a.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    return bool((grown & b).any())


def _cause(k: int, parts: list[dict], found: dict, masks, named_m: float
           ) -> tuple[str, str]:
    """(cause, detail) of ground-truth part ``k`` that has no pose of its class within 5 cm."""
    t = np.array(parts[k]['cam_t_m2c']) / 1000
    near = sorted(((float(np.linalg.norm(T[:3, 3] - t)), obj) for obj, Ts in found.items()
                   for T in Ts), key=lambda x: x[0])
    near = [(d, obj) for d, obj in near if d <= NEAR_M]
    if not near:
        return 'missed', ''
    d, obj = near[0]
    if d <= named_m and obj != parts[k]['obj_id']:
        return 'named', f'{parts[k]["obj_id"]}->{obj} at {100 * d:.1f} cm'
    for T in (T for Ts in found.values() for T in Ts):
        dist = float(np.linalg.norm(T[:3, 3] - t))
        if dist > NEAR_M:
            continue
        for j, other in enumerate(parts):
            t_j = np.array(other['cam_t_m2c']) / 1000
            if j != k and other['obj_id'] in found and \
                    any(np.allclose(T, U) for U in found[other['obj_id']]) and \
                    np.linalg.norm(T[:3, 3] - t_j) < dist and _touching(masks[k], masks[j]):
                return 'merged', f'with obj {other["obj_id"]}'
    return 'other', f'nearest obj {obj} at {100 * d:.1f} cm'


def none_parts(scenes: Path, estimates: Path, named_m: float) -> list[dict]:
    """One row per "none" part: scene, im, gt index, obj, visib, cause, detail."""
    est = _estimates(estimates)
    rows = []
    for scene in sorted((scenes / 'test_side').iterdir()):
        gt = json.loads((scene / 'scene_gt.json').read_text())
        info = json.loads((scene / 'scene_gt_info.json').read_text())
        for im, parts in gt.items():
            found = {obj: est[(int(scene.name), int(im), obj)] for obj in
                     {o for (s, i, o) in est if s == int(scene.name) and i == int(im)}}
            masks = None
            for k, part in enumerate(parts):
                t = np.array(part['cam_t_m2c']) / 1000
                if any(np.linalg.norm(T[:3, 3] - t) <= NEAR_M
                       for T in found.get(part['obj_id'], [])):
                    continue
                masks = masks or _masks(scene, int(im), len(parts))
                cause, detail = _cause(k, parts, found, masks, named_m)
                rows.append({'scene': int(scene.name), 'im': int(im), 'gt': k,
                             'obj': part['obj_id'],
                             'visib': round(info[im][k].get('visib_fract', 0.0), 2),
                             'cause': cause, 'detail': detail})
    return rows


def rerun(rows: list[dict], scenes: Path, classifier: Path, templates: Path) -> None:
    """Add the rerun's columns to ``rows`` (see the module's docstring)."""
    from tlessbot_ros.core.common import SIDE, TOP, CameraMount, Rig
    from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
    from tlessbot_ros.core.pose import TemplateDatabase
    from tlessbot_ros.core.recognise import LinearClassifier
    from tlessbot_ros.io.bop import read_split

    class Recording:
        """The classifier, keeping the summed scores it ranks."""

        def __init__(self, inner) -> None:
            self.inner = inner

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def predict_scores(self, scores, **kw):
            scored.append(np.asarray(scores))
            return self.inner.predict_scores(scores, **kw)

    model = Recording(LinearClassifier.load(classifier))
    database = TemplateDatabase.load(templates)
    wanted = {(r['scene'], r['im']) for r in rows}
    pipeline = None
    stash: list[np.ndarray] = []     # the instances the classifier ranked, in its order
    scored: list[np.ndarray] = []    # their summed scores (the first call of a frame)
    readers = [read_split(scenes, f'test_{v}') for v in (TOP, SIDE)]
    for top, side in zip(*readers):
        if (side.scene_id, side.im_id) not in wanted:
            continue
        by_view = {TOP: top, SIDE: side}
        if pipeline is None:
            rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                       for v, im in by_view.items()})
            pipeline = PerceptionPipeline(rig=rig, classifier=model, templates=database)
            classify = pipeline.classify

            def classify_kept(*a, **kw):
                guesses = classify(*a, **kw)
                stash.append(np.array(list(guesses)))
                return guesses

            pipeline.classify = classify_kept   # type: ignore[method-assign]
        stash.clear()
        scored.clear()
        result = pipeline.process({v: ViewInput(im.rgb, im.depth_m, im.intrinsics,
                                                im.T_world_camera) for v, im in by_view.items()})
        labels = result.labels[SIDE]
        ranked = model.ranked_classes(scored[0], 99) if scored and stash else None
        row_of = {int(i): n for n, i in enumerate(stash[0])} if stash else {}
        dets = {d.instance_id: d for d in result.detections}
        for r in (r for r in rows if (r['scene'], r['im']) == (side.scene_id, side.im_id)):
            mask = side.gt[r['gt']].mask
            inst, share, merged = 0, 0.0, False
            if mask is not None and mask.any():
                values, counts = np.unique(labels[mask], return_counts=True)
                keep = values != 0
                if keep.any():
                    values, counts = values[keep], counts[keep]
                    inst, share = int(values[counts.argmax()]), counts.max() / mask.sum()
                    region = labels == inst
                    merged = any(j != r['gt'] and g.mask is not None and
                                 (region & g.mask).sum() >= 0.2 * region.sum()
                                 for j, g in enumerate(side.gt))
            det = dets.get(inst)
            rank = -1
            if inst and ranked is not None and inst in row_of and row_of[inst] < len(ranked):
                order = list(ranked[row_of[inst]])
                rank = order.index(r['obj']) + 1 if r['obj'] in order else -1
            r.update({'inst': inst, 'share': round(float(share), 2), 'inst_merged': merged,
                      'rank': rank, 'fitted': det.obj_id if det else '',
                      'pose_ok_class': bool(det and det.obj_id == r['obj'])})


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('scenes', type=Path)
    ap.add_argument('models', type=Path)
    ap.add_argument('estimates', type=Path)
    ap.add_argument('--manifest', type=Path)
    ap.add_argument('--named-cm', type=float, default=1.5)
    ap.add_argument('--rerun', action='store_true')
    ap.add_argument('--classifier', type=Path)
    ap.add_argument('--templates', type=Path)
    args = ap.parse_args()
    rows = none_parts(args.scenes, args.estimates, args.named_cm / 100)
    names: dict[int, str] = {}
    pairs: set[tuple[str, str]] = set()
    if args.manifest:
        for p in json.loads(args.manifest.read_text())['parts']:
            names[p['id']] = p['name']
            pairs |= {(p['name'], q) for q in p['lookalikes']}
    for r in rows:
        if r['cause'] == 'named':
            a, b = (int(x) for x in r['detail'].split()[0].split('->'))
            r['lookalike'] = (names.get(a), names.get(b)) in pairs
    if args.rerun:
        rerun(rows, args.scenes, args.classifier, args.templates)
    print('causes: ' + ', '.join(f'{k} {v}' for k, v in sorted(Counter(
        r['cause'] for r in rows).items())) + f' (of {len(rows)})')
    for r in rows:
        r['name'] = names.get(r['obj'], '')
        print('  ' + ' '.join(f'{k}={v}' for k, v in r.items()))
    by_obj: dict[str, Counter] = defaultdict(Counter)
    for r in rows:
        by_obj[r['name'] or str(r['obj'])][r['cause']] += 1
    for name, c in sorted(by_obj.items()):
        print(f'  {name}: ' + ', '.join(f'{k} {v}' for k, v in sorted(c.items())))


if __name__ == '__main__':
    main()
