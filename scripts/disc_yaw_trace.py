"""Why a round flat part (a disc with holes) ends off in yaw: the resting prior's path for it
on chosen frames of a bench cell (docs/bench/smoothed-disc-yaw.md; the pipeline runs as
``tlessbot evaluate`` runs it, in this process, with hooks around ``core/resting_check.py``).

    PYTHONPATH=TREE python scripts/disc_yaw_trace.py SCENES PARTS FRAMES [OBJ_IDS]

SCENES: a scenes folder (test_top, test_side); PARTS: its parts folder (models, templates,
classifier); FRAMES and OBJ_IDS comma-separated (OBJ_IDS: default every part with a listed
hole yaw period). Per call of the prior on such a part: the fit's tilt and contact, the path
taken (levelled or rested), the edge search's reach, its turn, the depth's fitness against
the fit's, whether the votes kept the fit; the rotation error to the truth (min over its
symmetries) of the pose before the call, of the edge-refined pose, and the final one.
"""
import json
import sys
from pathlib import Path

import numpy as np

import tlessbot_ros.core.resting_check as rc
from tlessbot_ros.core.common import SIDE, TOP
from tlessbot_ros.core.common.symmetry import symmetries_from_models_info
from tlessbot_ros.core.metrics import pose_error
from tlessbot_ros.core.pipeline import ViewInput
from tlessbot_ros.core.pose import PoseParams, TemplateDatabase
from tlessbot_ros.core.pose.flat_yaw import hole_yaw_period
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.tools.support.eval_frames import _first_pipeline
from tlessbot_ros.tools.support.overrides import stage_overrides

STATE: dict = {}
LEVEL, ON_EDGES, REFINE = rc._level, rc._on_edges, rc.refine_on_edges


def refine(scene, T, T_world_camera, points_o, views, **kw):
    """The edge search, with its candidate's error and the edges' score (px) at the truth
    (the same search from the true pose with nothing to move)."""
    moved, found = REFINE(scene, T, T_world_camera, points_o, views, **kw)
    obj_id = STATE.get('obj_id')
    if obj_id is None:
        return moved, found
    gt = _truth(obj_id, T)
    at_truth = '-'
    if gt is not None:
        still = dict(kw, max_yaw_deg=0.0, max_shift_m=1e-6)
        # the edges' score at the truth: the search's own score from that pose, not moved
        scored = REFINE(scene, gt.T_camera_object, T_world_camera, points_o, views, **still)
        at_truth = f"{scored[1]['edge_before_px']:.3f}"
    print(f'   search ±{kw["max_yaw_deg"]:.0f}°: turn {found["edge_yaw_deg"]:.2f}° shift '
          f'{1e3 * found["edge_shift_m"]:.1f} mm, candidate {_err(obj_id, moved)}; edges px: fit '
          f'{found["edge_before_px"]:.3f}, candidate {found["edge_after_px"]:.3f}, truth '
          f'{at_truth}; reach {found["edge_reach_px"]:.0f} px', flush=True)
    return moved, found


def _truth(obj_id, T):
    gts = [g for g in STATE['image'].gt if g.obj_id == obj_id]
    if not gts:
        return None
    return min(gts, key=lambda g: np.linalg.norm(g.T_camera_object[:3, 3] - T[:3, 3]))


def _err(obj_id, T):
    gt = _truth(obj_id, T)
    if gt is None or T is None:
        return '-'
    e = pose_error(T, gt.T_camera_object, STATE['symmetries'][obj_id])
    # the angle between the discs' axes (either way up): what is not a turn about the axis
    axes = np.degrees(np.arccos(min(1.0, abs(float(T[:3, 2] @ gt.T_camera_object[:3, 2])))))
    return f'{e.rotation_deg:.1f}°/{1e3 * e.translation_m:.0f}mm (axes {axes:.1f}°)'


def _wanted(pipeline, obj_id):
    only = STATE['only']
    if only:
        return obj_id in only
    return hole_yaw_period(pipeline.pose_estimator.database[obj_id]) > 0


def on_edges(refiner, obj, mesh, T, scene_c, job, evidence, params, info, **kw):
    moved = ON_EDGES(refiner, obj, mesh, T, scene_c, job, evidence, params, info, **kw)
    max_yaw_deg = kw.get('max_yaw_deg')
    if STATE.get('obj_id') is None:
        return moved
    STATE['edges'].append((max_yaw_deg, _err(job.detection.obj_id, T),
                           _err(job.detection.obj_id, moved), moved is not T))
    return moved


def level(pipeline, job, views, labels):
    d = job.detection
    if d.pose is None or not _wanted(pipeline, d.obj_id):
        STATE['obj_id'] = None
        return LEVEL(pipeline, job, views, labels)
    before = d.pose.T_camera_object.copy()
    STATE['obj_id'] = d.obj_id
    STATE['edges'] = []
    info, refined = LEVEL(pipeline, job, views, labels)
    STATE['obj_id'] = None
    keys = ('rest_tilt_deg', 'rest_contact_m', 'rest_noise_m', 'rest_tolerance_m',
            'rest_fitness', 'rest_best_fitness', 'rest_levelled', 'edge_yaw_deg',
            'edge_shift_m', 'edge_depth_fitness', 'rest_votes_kept', 'rest_edge_rested')
    shown = {k: round(float(info[k]), 4) for k in keys if info and k in info}
    print(f'## frame {STATE["image"].im_id} obj {d.obj_id} inst {d.instance_id}: before '
          f'{_err(d.obj_id, before)}, after {_err(d.obj_id, d.pose.T_camera_object)}, '
          f'refined {"-" if refined is None else _err(d.obj_id, refined[0])}', flush=True)
    for reach, e0, e1, moved in STATE['edges']:
        print(f'   edges: reach {reach} from {e0} to {e1} (taken by depth: {moved})')
    print(f'   info {shown}', flush=True)
    return info, refined


def main() -> None:
    scenes, parts = Path(sys.argv[1]), Path(sys.argv[2])
    frames = {int(x) for x in sys.argv[3].split(',')}
    STATE['only'] = {int(x) for x in sys.argv[4].split(',')} if len(sys.argv) > 4 else set()
    info = json.loads((scenes / 'models_info.json').read_text())
    STATE['symmetries'] = {int(k): symmetries_from_models_info(v) for k, v in info.items()}
    templates = TemplateDatabase.load(parts / 'templates.npz')
    classifier = LinearClassifier.load(parts / 'classifier.npz')
    rc._level, rc._on_edges, rc.refine_on_edges = level, on_edges, refine
    readers = {v: read_split(scenes, f'test_{v}') for v in (TOP, SIDE)}
    pipeline = None
    for images in zip(*readers.values()):
        if images[0].im_id not in frames:
            continue
        by_view = dict(zip((TOP, SIDE), images))
        STATE['image'] = by_view[SIDE]
        inputs = {v: ViewInput(i.rgb, i.depth_m, i.intrinsics, i.T_world_camera)
                  for v, i in by_view.items()}
        if pipeline is None:
            pipeline = _first_pipeline(by_view, classifier=classifier, templates=templates,
                                       pose=PoseParams(), **stage_overrides(None))
        result = pipeline.process(inputs)
        for d in result.detections:
            if d.view == SIDE and d.pose is not None and _wanted(pipeline, d.obj_id):
                print(f'   final frame {images[0].im_id} obj {d.obj_id} inst {d.instance_id}: '
                      f'{_err(d.obj_id, d.pose.T_camera_object)}', flush=True)


if __name__ == '__main__':
    main()
