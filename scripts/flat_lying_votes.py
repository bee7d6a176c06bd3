"""The flat check's aligned votes on chosen frames of a bench cell, at the fit and at the truth
(diagnosis of docs/bench/flat-lying.md; the pipeline runs as ``tlessbot evaluate`` runs it, with
a hook around ``check_flat``).

    PYTHONPATH=TREE python scripts/flat_lying_votes.py BENCH SEED SET FRAMES [OBJ_IDS]

BENCH: a bench folder (``/work/bench50``: ``scenes/SEED/SET`` and ``parts/SET``); FRAMES and
OBJ_IDS comma-separated. Per flat part fitted in those frames: which exact half turn of the fit
(``outline_half_turns``: 1, 2 about the outline's axes, 3 about the thin axis) is nearest the
true pose, the fit's error; the duels' votes [i, j] (pixels for i against j) of the fit and its
turns, of the true pose and its turns, and of the fit with its yaw checked first on the
silhouette (``refine_yaw``); what the check decided and the final error.
"""
import sys
from pathlib import Path

import numpy as np

import tlessbot_ros.core.flat_parts as fp
from tlessbot_ros.core.common import SIDE, TOP, rotation_angle_deg
from tlessbot_ros.core.pipeline import ViewInput
from tlessbot_ros.core.pose import PoseParams, TemplateDatabase
from tlessbot_ros.core.pose.flat_align import view_votes
from tlessbot_ros.core.pose.flat_turns import mesh_scene, outline_half_turns, refine_yaw
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.tools.support.eval_frames import _first_pipeline
from tlessbot_ros.tools.support.overrides import stage_overrides

CURRENT = {}
ORIGINAL = fp.check_flat


def _error(T, G):
    return (np.linalg.norm(T[:3, 3] - G[:3, 3]) * 1000, rotation_angle_deg(T[:3, :3], G[:3, :3]))


def _votes(pipeline, job, evidence, poses, mesh):
    obj = pipeline.pose_estimator.database[job.detection.obj_id]
    params = fp.flat_check(pipeline).params
    return view_votes([mesh] * len(poses), poses, obj.model_points.astype(np.float64), evidence,
                      align_at_1m_m=params.align_at_1m_m,
                      tolerance_m=params.depth_tolerance_m).tolist()


def hooked(pipeline, job, views, labels):
    d = job.detection
    obj = pipeline.pose_estimator.database[d.obj_id] if d.pose is not None else None
    only = CURRENT['only']
    if obj is None or not fp.flat_check(pipeline).applies(obj) or (only and d.obj_id not in only):
        return ORIGINAL(pipeline, job, views, labels)
    T0 = np.array(d.pose.T_camera_object)
    family = [d.obj_id, *obj.lookalikes]
    gts = [g for g in CURRENT['views'][d.view].gt if g.obj_id in family] or \
        CURRENT['views'][d.view].gt
    G = min(gts, key=lambda g: np.linalg.norm(g.T_camera_object[:3, 3] - T0[:3, 3])
            ).T_camera_object
    turns = outline_half_turns(obj.model_points.astype(np.float64))
    mesh = mesh_scene(obj)
    evidence = fp.colour_views(views, labels, d.instance_id, d.view,
                               fp.table_frames(pipeline, views))
    fit = [T0] + [T0 @ t for t in turns]
    near = min(range(4), key=lambda k: rotation_angle_deg(fit[k][:3, :3], G[:3, :3]))
    T_yaw, yaw = refine_yaw(fp.flat_check(pipeline), obj, T0, job.T_world_camera, evidence)
    lines = [
        f'   fit round (0 the fit, 1-3 its turns): {_votes(pipeline, job, evidence, fit, mesh)}',
        f'   truth round (0 the truth): '
        f'{_votes(pipeline, job, evidence, [G] + [G @ t for t in turns], mesh)}',
        f'   yaw checked first ({yaw:.1f} deg; face err '
        f'{_error(T_yaw @ np.linalg.inv(T0) @ fit[near], G)[1]:.1f} deg): '
        f'{_votes(pipeline, job, evidence, [T_yaw] + [T_yaw @ t for t in turns], mesh)}']
    info = ORIGINAL(pipeline, job, views, labels)
    e0, ef = _error(fit[near], G), _error(np.array(d.pose.T_camera_object), G)
    print(f'## {CURRENT["name"]} frame {CURRENT["im"]} obj {d.obj_id} ({d.view}): true face = '
          f'turn {near} of the fit, off {e0[0]:.1f} mm {e0[1]:.1f} deg; final obj {d.obj_id} '
          f'off {ef[0]:.1f} mm {ef[1]:.1f} deg', *lines,
          f'   decided: {({k: round(v, 2) for k, v in (info or {}).items()})}', sep='\n',
          flush=True)
    return info


def main() -> None:
    bench, seed, kset = Path(sys.argv[1]), sys.argv[2], sys.argv[3]
    frames = {int(x) for x in sys.argv[4].split(',')}
    CURRENT.update(only={int(x) for x in sys.argv[5].split(',')} if len(sys.argv) > 5 else set(),
                   name=f'{kset} {seed}')
    dataset = bench / 'scenes' / seed / kset
    templates = TemplateDatabase.load(bench / 'parts' / kset / 'templates.npz')
    classifier = LinearClassifier.load(bench / 'parts' / kset / 'classifier.npz')
    fp.check_flat = hooked
    readers = {v: read_split(dataset, f'test_{v}') for v in (TOP, SIDE)}
    pipeline = None
    for images in zip(*readers.values()):
        if images[0].im_id not in frames:
            continue
        by_view = dict(zip((TOP, SIDE), images))
        CURRENT.update(views=by_view, im=images[0].im_id)
        inputs = {v: ViewInput(i.rgb, i.depth_m, i.intrinsics, i.T_world_camera)
                  for v, i in by_view.items()}
        if pipeline is None:
            pipeline = _first_pipeline(by_view, classifier=classifier, templates=templates,
                                       pose=PoseParams(), **stage_overrides(None))
        pipeline.process(inputs)


if __name__ == '__main__':
    main()
