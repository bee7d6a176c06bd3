"""Every flat part lying on a face that a run lost, with its frame and how it ended
(docs/bench/flat-lying.md).

    PYTHONPATH=TREE python scripts/flat_lying_why.py RESULTS SEED/SET ...

RESULTS: an ev.sh out folder (RESULTS/SEED/SET/estimates.csv); the scenes and models are read
from /work/bench50. Flat: thinnest side <= 6 mm; lying: thin axis within 20 deg of the vertical;
lost: no estimate of its class within 5 cm / 5 deg. Causes: no estimate of its class within 5 cm
("named objN" when another class's estimate lies within 2 cm, "merged?" within 5 cm, with the
ground-truth parts nearest that estimate; "missed" else), or the nearest estimate wrong by
upside-down / yaw / tilt (the gravity direction in the part off by >100 / <5 / 5-100 deg,
with the error's axis in the model frame).
"""

import csv
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common.symmetry import symmetries_from_models_info
from tlessbot_ros.core.metrics import pose_error


def ang_r(A, B):
    return np.degrees(np.arccos(np.clip((np.trace(A.T @ B) - 1) / 2, -1, 1)))


def load_est(p):
    est = defaultdict(list)
    for row in csv.DictReader(open(p)):
        T = np.eye(4)
        T[:3, :3] = np.array(row['R'].split(), float).reshape(3, 3)
        T[:3, 3] = np.array(row['t'].split(), float) / 1000
        est[(int(row['scene_id']), int(row['im_id']))].append(
            (int(row['obj_id']), T, float(row['score']))
        )
    return est


def run(scenes, models, est_csv, tag, flat_mm=6.0, show_all=False):  # noqa: C901
    info = json.loads((models / 'models_info.json').read_text())
    est = load_est(est_csv)
    rows = []
    for sdir in sorted((scenes / 'test_side').iterdir()):
        gt = json.loads((sdir / 'scene_gt.json').read_text())
        cam = json.loads((sdir / 'scene_camera.json').read_text())
        sid = int(sdir.name)
        for im, objs in gt.items():
            up = np.array(cam[im]['cam_R_w2c']).reshape(3, 3) @ np.array([0, 0, 1.0])
            E = est.get((sid, int(im)), [])
            for gi, o in enumerate(objs):
                oid = o['obj_id']
                e = info[str(oid)]
                size = np.array([e['size_x'], e['size_y'], e['size_z']])
                if size.min() > flat_mm:
                    continue
                R = np.array(o['cam_R_m2c']).reshape(3, 3)
                tg = np.array(o['cam_t_m2c']) / 1000
                thin = np.eye(3)[int(np.argmin(size))]
                a = np.degrees(np.arccos(min(1, abs((R @ thin) @ up))))
                if a >= 20:
                    continue
                Tg = np.eye(4)
                Tg[:3, :3] = R
                Tg[:3, 3] = tg
                sym = symmetries_from_models_info(e)
                mine = [(T, s) for (k, T, s) in E if k == oid]
                ok = any(
                    pose_error(T, Tg, sym).rotation_deg < 5
                    and pose_error(T, Tg, sym).translation_m < 0.05
                    for T, _ in mine
                )
                if ok and not show_all:
                    continue
                near = [(k, np.linalg.norm(T[:3, 3] - tg), s) for (k, T, s) in E]
                if ok:
                    cause = 'ok'
                elif not mine or min(np.linalg.norm(T[:3, 3] - tg) for T, _ in mine) > 0.05:
                    oth = sorted([n for n in near if n[0] != oid], key=lambda n: n[1])
                    # the neighbours: other GT parts near the nearest estimate
                    if oth:
                        ke = [
                            T
                            for (k, T, s) in E
                            if k == oth[0][0]
                            and abs(np.linalg.norm(T[:3, 3] - tg) - oth[0][1]) < 1e-9
                        ][0]
                        gn = sorted(
                            (
                                np.linalg.norm(np.array(q['cam_t_m2c']) / 1000 - ke[:3, 3]) * 1000,
                                q['obj_id'],
                            )
                            for q in objs
                        )
                        extra = ' | GT near that estimate: ' + ', '.join(
                            f'obj{q}@{d:.0f}' for d, q in gn[:3]
                        )
                    else:
                        extra = ''
                    if oth and oth[0][1] < 0.02:
                        cause = f'named obj{oth[0][0]} ({oth[0][1] * 1000:.0f}mm)'
                    elif oth and oth[0][1] < 0.05:
                        cause = f'merged? nearest obj{oth[0][0]} at {oth[0][1] * 1000:.0f}mm'
                    else:
                        cause = 'missed' if not mine else 'far'
                    cause += extra
                else:
                    T = min(mine, key=lambda m: np.linalg.norm(m[0][:3, 3] - tg))[0]
                    Ss = list(sym.transforms(step_rad=np.radians(1)))
                    best = min(Ss, key=lambda S: ang_r(T[:3, :3], R @ S[:3, :3]))
                    Rs = R @ best[:3, :3]
                    err = ang_r(T[:3, :3], Rs)
                    tilt = np.degrees(np.arccos(np.clip((T[:3, :3].T @ up) @ (Rs.T @ up), -1, 1)))
                    dt = np.linalg.norm(T[:3, 3] - tg) * 1000
                    if err < 5:
                        cause = f'translation {dt:.0f}mm'
                    else:
                        k = (
                            'yaw'
                            if tilt < 5
                            else (
                                'tilt5-20'
                                if tilt < 20
                                else ('tilt20-100' if tilt < 100 else 'upside-down')
                            )
                        )
                        # rotation axis of the error in the model frame
                        D = Rs.T @ T[:3, :3]
                        w, V = np.linalg.eig(D)
                        ax = np.real(V[:, np.argmin(abs(w - 1))])
                        cause = (f'{k} err={err:.0f} tilt={tilt:.0f} '
                                 f'axis_model={np.round(ax, 2)} dt={dt:.0f}mm')
                vis = None
                gi_p = sdir / 'scene_gt_info.json'
                if gi_p.exists():
                    vis = json.loads(gi_p.read_text())[im][gi].get('visib_fract')
                rows.append(
                    (tag, int(im), oid, f'vis={vis:.2f}' if vis is not None else '', cause)
                )
    return rows


if __name__ == '__main__':
    R = sys.argv[1]
    cells = sys.argv[2:]
    B = Path('/work/bench50')
    for c in cells:
        S, K = c.split('/')
        for r in run(
            B / 'scenes' / S / K,
            B / 'parts' / K / 'models',
            Path(R) / S / K / 'estimates.csv',
            f'{K} {S}',
        ):
            print(*r, sep='\t')
