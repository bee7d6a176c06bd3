"""Every call of the flat check's depth turn on a cell, with its votes and the truth
(docs/bench/pile-flat-flips.md; the pipeline runs as ``tlessbot evaluate`` runs it, with a hook
around ``FlatCheck.depth_turn``).

    PYTHONPATH=TREE python scripts/depth_turn_votes.py SCENES PARTS OUT.jsonl [--frames 3,9]

SCENES: a two-view scenes folder (``/work/bench-pile/4100-g``); PARTS: its parts folder
(``templates.npz``, ``classifier.npz``). One JSON line per call: frame, class, the pose's
rotation error against the nearest true part of its class within 2 cm (``err0``, deg; -1 when
none), the same for the pose refitted to the depth (``err0_refit``), and per principal half
turn (refitted, as the check does) its rotation error and its votes (pixels for, against, the
pooled vote: 0 without a clear margin) against the pose as it is (``as_is``), against the pose
refitted alike (``refit``) and over the pixels where both meshes are hit (``hits``); then what
the check returned (``applied_vote``, ``applied_err``).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import tlessbot_ros.core.flat_parts as fp
from tlessbot_ros.core.common import TOP, rotation_angle_deg
from tlessbot_ros.core.pose import PoseParams, TemplateDatabase, lookalike
from tlessbot_ros.core.pose import flat as flat_module
from tlessbot_ros.core.pose.flat_turns import mesh_scene, principal_half_turns, refit_to_surface
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.tools.support.eval_frames import _first_pipeline, two_view_frames
from tlessbot_ros.tools.support.overrides import stage_overrides

STATE: dict = {}
CHECK_FLAT = fp.check_flat
DEPTH_TURN = flat_module.FlatCheck.depth_turn


def _errors(mesh, T, points, plane):
    hit = np.isfinite(lookalike.depth_along(mesh, T, points / points[:, 2:3]))
    return lookalike.depth_errors(mesh, T, points, plane), hit


def _vote(challenger, incumbent, params, hits_only=False):
    favour = against = 0
    for (errors_a, hit_a), (errors_b, hit_b) in zip(challenger, incumbent):
        keep = hit_a & hit_b if hits_only else np.ones(len(errors_a), bool)
        f, a = lookalike.vote_counts(errors_a[keep], errors_b[keep], params.depth_tolerance_m)
        favour, against = favour + f, against + a
    total = sum(len(e) for e, _ in incumbent)
    clear = lookalike.clear_margin(favour, against, params.depth_min_z)
    return [favour, against, (favour - against) / total if clear and total else 0.0]


def _angle(T, G):
    return -1.0 if G is None else float(rotation_angle_deg(np.asarray(T)[:3, :3], G[:3, :3]))


def traced_depth_turn(self, obj, T_camera_object, points_c, more_views=(), T_world_camera=None):
    result = DEPTH_TURN(self, obj, T_camera_object, points_c, more_views, T_world_camera)
    mesh = mesh_scene(obj)
    if mesh is None or obj.mesh_vertices is None:
        return result
    T0 = np.asarray(T_camera_object, np.float64)
    clouds = [(np.eye(4), np.asarray(points_c, np.float64))] + \
        [(np.asarray(T, np.float64), points) for points, T in more_views]
    planes = lookalike.view_planes(T_world_camera, [T for T, _ in clouds[1:]])
    clouds = [(T, p, plane) for (T, p), plane in zip(clouds, planes) if len(p)]
    G = STATE['truth'](obj.obj_id, T0)
    T0_refit = refit_to_surface(obj, T0, points_c)
    as_is = [_errors(mesh, T @ T0, p, plane) for T, p, plane in clouds]
    refit = [_errors(mesh, T @ T0_refit, p, plane) for T, p, plane in clouds]
    record = {'frame': STATE['frame'], 'obj': obj.obj_id, 'err0': _angle(T0, G),
              'err0_refit': _angle(T0_refit, G), 'turns': [],
              'applied_vote': result[1],
              'applied_err': None if result[0] is None else _angle(result[0], G)}
    for turn in obj.derived('half_turns', lambda: principal_half_turns(obj.mesh_vertices)):
        turned = refit_to_surface(obj, T0 @ turn, points_c)
        errors = [_errors(mesh, T @ turned, p, plane) for T, p, plane in clouds]
        record['turns'].append({'err': _angle(turned, G),
                                'as_is': _vote(errors, as_is, self.params),
                                'refit': _vote(errors, refit, self.params),
                                'hits': _vote(errors, as_is, self.params, hits_only=True)})
    STATE['out'].write(json.dumps(record) + '\n')
    STATE['out'].flush()
    return result


def hooked_check_flat(pipeline, job, views, labels):
    STATE['view'] = job.detection.view
    return CHECK_FLAT(pipeline, job, views, labels)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('scenes', type=Path)
    ap.add_argument('parts', type=Path)
    ap.add_argument('out', type=Path)
    ap.add_argument('--frames', default='')
    args = ap.parse_args()
    frames = {int(x) for x in args.frames.split(',') if x}
    fp.check_flat = hooked_check_flat
    flat_module.FlatCheck.depth_turn = traced_depth_turn
    templates = TemplateDatabase.load(args.parts / 'templates.npz')
    classifier = LinearClassifier.load(args.parts / 'classifier.npz')
    STATE['out'] = args.out.open('w')
    pipeline = None
    for by_view, inputs in two_view_frames(args.scenes, frames or None):

        def truth(obj_id, T0, by_view=by_view):
            parts = [g.T_camera_object for g in by_view[STATE['view']].gt if g.obj_id == obj_id]
            near = min(parts, key=lambda G: np.linalg.norm(G[:3, 3] - T0[:3, 3]), default=None)
            return near if near is not None and \
                np.linalg.norm(near[:3, 3] - T0[:3, 3]) < 0.02 else None

        STATE.update(frame=by_view[TOP].im_id, truth=truth)
        if pipeline is None:
            pipeline = _first_pipeline(by_view, classifier=classifier, templates=templates,
                                       pose=PoseParams(), **stage_overrides(None))
        pipeline.process(inputs)


if __name__ == '__main__':
    main()
