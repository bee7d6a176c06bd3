"""The aligned votes of each flat part's TRUE pose against its three half turns, split by view
and cue (height, colour), on chosen frames of a cell; then how the check ended
(docs/bench/smoothed-depth-flat.md: which evidence a smoothed depth takes away).

    PYTHONPATH=TREE python scripts/flat_lying_cues.py BENCH SEED SET FRAMES [OBJ_IDS]

Arguments as ``scripts/flat_lying_votes.py``'s (BENCH: ``scenes/SEED/SET``, ``parts/SET``), whose
pipeline and hook it reuses. Only parts fitted within 5 cm of a true part of their class are
shown. A line per turn: ``[viewN: height F:A colour F:A]``, pixels for (F) and against (A) the
true pose in view N.
"""
import dataclasses

import flat_lying_votes as votes_script
import numpy as np

import tlessbot_ros.core.flat_parts as fp
import tlessbot_ros.core.pose.flat_align as fa
from tlessbot_ros.core.common import rotation_angle_deg
from tlessbot_ros.core.pose.flat_turns import mesh_scene, outline_half_turns

SPLIT: list[tuple[int, int, int, int]] = []
PIXEL_VOTES = fa.pixel_votes


def split_votes(view, a, b, tolerance_m):
    """:func:`flat_align.pixel_votes`, its colour share recorded apart (the same view with no
    depth votes on colour only)."""
    favour, against = PIXEL_VOTES(view, a, b, tolerance_m)
    no_depth = dataclasses.replace(view, height=np.full_like(view.height, np.nan))
    colour_for, colour_against = PIXEL_VOTES(no_depth, a, b, tolerance_m)
    SPLIT.append((favour - colour_for, against - colour_against, colour_for, colour_against))
    return favour, against


def hooked(pipeline, job, views, labels):
    d = job.detection
    current = votes_script.CURRENT
    obj = pipeline.pose_estimator.database[d.obj_id] if d.pose is not None else None
    if obj is None or not fp.flat_check(pipeline).applies(obj) or \
            (current['only'] and d.obj_id not in current['only']):
        return votes_script.ORIGINAL(pipeline, job, views, labels)
    T0 = np.array(d.pose.T_camera_object)
    truths = [g.T_camera_object for g in current['views'][d.view].gt if g.obj_id == d.obj_id]
    G = min(truths, key=lambda T: np.linalg.norm(T[:3, 3] - T0[:3, 3]), default=None)
    if G is None or np.linalg.norm(G[:3, 3] - T0[:3, 3]) > 0.05:
        return votes_script.ORIGINAL(pipeline, job, views, labels)
    mesh, points = mesh_scene(obj), obj.model_points.astype(np.float64)
    evidence = fp.colour_views(views, labels, d.instance_id, d.view,
                               fp.table_frames(pipeline, views))
    params = fp.flat_check(pipeline).params
    for k, turn in enumerate(outline_half_turns(points), 1):
        SPLIT.clear()
        fa.view_votes([mesh, mesh], [G, G @ turn], points, evidence,
                      align_at_1m_m=params.align_at_1m_m, tolerance_m=params.depth_tolerance_m)
        cues = ' '.join(f'[view{n}: height {h1}:{h2} colour {c1}:{c2}]'
                        for n, (h1, h2, c1, c2) in enumerate(SPLIT))
        print(f'{current["name"]} f{current["im"]} obj{d.obj_id} fit@{d.view} truth vs '
              f'turn{k}: {cues}', flush=True)
    info = votes_script.ORIGINAL(pipeline, job, views, labels) or {}
    error = rotation_angle_deg(np.array(d.pose.T_camera_object)[:3, :3], G[:3, :3])
    print(f'   final rotation error {error:.1f} deg; align_winner {info.get("align_winner")} '
          f'decided {info.get("align_decided")}', flush=True)
    return info


if __name__ == '__main__':
    fa.pixel_votes = split_votes
    votes_script.hooked = hooked
    votes_script.main()
