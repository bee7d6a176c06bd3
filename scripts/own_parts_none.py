"""Every part with no pose of its class within 5 cm ("none" of own_parts_why.py), by cause.

    python scripts/own_parts_none.py SCENES MODELS ESTIMATES_CSV [--manifest PARTS/manifest.json]
        [--templates T.npz [--rerun --classifier C.npz]] [--named-cm 1.5]

From the estimates alone, each "none" part is

* ``missed``: no estimate of any class within 5 cm of its centre;
* ``named``: an estimate of another class within ``--named-cm`` (the pair, and whether the
  manifest lists the two as look-alikes);
* ``merged``: the nearest estimate within 5 cm is the pose of a neighbour (its class, nearer to
  the neighbour's centre than to this part's) whose side-view mask touches this part's;
* ``other``: anything else (an estimate of another class 1.5-5 cm off, not a neighbour's).

With ``--templates`` (meshes kept), each part named as its listed look-alike is also scored at
its TRUE pose: do its two views show the difference at all (``shows``)? Where they do not
(the holes that tell a mirror bracket from its twin seen edge-on), no check after the fit can
name it; only the classifier's guess, or another view.

With ``--rerun`` the pipeline runs again (as ``tlessbot evaluate``) on the frames that hold a
"none" part and says, for each, which instance of the side view holds most of it and its
share of the part's pixels, the classifier's rank of the right class on that instance (1 =
first, -1 not ranked) and the class the pose stage kept; ``why`` is then ``localiser`` (no
instance holds it), ``split`` (none holds half of it), ``merged`` (its instance also holds
>= 20 % of another part) or the cause above. A rerun is a new run: Open3D's RANSAC and the
fallback's time budget move about one part a cell between runs.
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


class KeepGuesses:
    """A pipeline's ``classify``, keeping the instances it ranked (in its order)."""

    def __init__(self, classify, stash: list[np.ndarray]) -> None:
        self.classify, self.stash = classify, stash

    def __call__(self, *args, **kwargs):
        guesses = self.classify(*args, **kwargs)
        self.stash.append(np.array(list(guesses)))
        return guesses


def twin_votes(rows: list[dict], scenes: Path, templates: Path) -> None:
    """For each part named as its listed look-alike: whether its views show the difference
    at the TRUE pose (the aligned height and colour votes of the flat check, both views,
    ground-truth masks as the parts' regions; :func:`~tlessbot_ros.core.pose.flat_align.
    view_votes`): 'truth_votes' = pixels for the truth / for the look-alike, 'shows' = a clear
    margin (``FlatParams.align_min_z``)."""
    from tlessbot_ros.core.common import SIDE, TOP, plane_of_frame, raycasting_scene
    from tlessbot_ros.core.pose import FlatParams, TemplateDatabase
    from tlessbot_ros.core.pose.flat import ViewEvidence
    from tlessbot_ros.core.pose.flat_align import view_votes
    from tlessbot_ros.core.pose.lookalike import clear_margin
    from tlessbot_ros.io.bop import read_split

    database = TemplateDatabase.load(templates)
    params = FlatParams()
    wanted = [r for r in rows if r.get('lookalike')]
    readers = [read_split(scenes, f'test_{v}') for v in (SIDE, TOP)]
    for side, top in zip(*readers):
        for r in (r for r in wanted if (r['scene'], r['im']) == (side.scene_id, side.im_id)):
            k, named = r['gt'], int(r['detail'].split()[0].split('->')[1])
            parts = [database[r['obj']], database[named]]
            if any(p.mesh_faces is None or p.mesh_vertices is None for p in parts):
                continue
            evidence = []
            for image in (side, top):
                mask = image.gt[k].mask
                if mask is None:
                    continue
                others = np.zeros_like(mask)
                for j, g in enumerate(image.gt):
                    if j != k and g.mask is not None:
                        others |= g.mask
                evidence.append(ViewEvidence(
                    image.rgb, mask, image.intrinsics,
                    np.linalg.inv(image.T_world_camera) @ side.T_world_camera, image.depth_m,
                    plane_of_frame(image.T_world_camera), others))
            T = side.gt[k].T_camera_object
            votes = view_votes([raycasting_scene(p.mesh_vertices, p.mesh_faces) for p in parts],
                               [T, T], parts[0].model_points.astype(np.float64), evidence,
                               align_at_1m_m=params.align_at_1m_m,
                               tolerance_m=params.depth_tolerance_m)
            r['truth_votes'] = f'{votes[0, 1]}/{votes[1, 0]}'
            r['shows'] = clear_margin(int(votes[0, 1]), int(votes[1, 0]), params.align_min_z)


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
            pipeline.classify = KeepGuesses(pipeline.classify, stash)   # type: ignore
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
                      'rank': rank, 'fitted': det.obj_id if det else ''})
            r['why'] = ('localiser' if inst == 0 else 'split' if share < 0.5 else
                        'merged' if merged else r['cause'])


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
    if args.templates:
        twin_votes(rows, args.scenes, args.templates)
    if args.rerun:
        rerun(rows, args.scenes, args.classifier, args.templates)
    for key in ('cause', 'why'):
        if any(key in r for r in rows):
            print(f'{key}: ' + ', '.join(f'{k} {v}' for k, v in sorted(Counter(
                r[key] for r in rows).items())) + f' (of {len(rows)})')
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
