"""Build the pose template database from CAD models (rendered side-camera turntable views).

    tlessbot templates --models ../shared/data/tless_models_cad_stl --out templates.npz

Each object rests in its most probable stable pose(s) on the table, seen by the rig's side camera
(config/cell.yaml, or the default rig), turned in --views yaw steps (paper: 12, 30° apart).
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from tlessbot_ros.errors import TlessbotError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', type=Path, required=True,
                        help='folder of obj_NN.stl|ply|obj CAD models (mm)')
    parser.add_argument('--out', type=Path, required=True, help='database to write (.npz)')
    parser.add_argument('--views', type=int, default=12,
                        help='turntable views per stable pose, 2-18 (paper: 12)')
    parser.add_argument('--ids', type=int, nargs='+', help='only these object ids')
    parser.add_argument('--stable-poses', type=int, default=1,
                        help='stable poses with templates per object (default 1)')
    parser.add_argument('--voxel-fraction', type=float, default=1.0 / 25.0,
                        help='voxel edge as a fraction of the object diameter (1/25)')
    parser.add_argument('--config', type=Path, default=None,
                        help='rig parameters YAML (default: config/cell.yaml if present)')
    parser.add_argument('--seed', type=int, default=0)


def _side_camera(config: Path | None):
    from tlessbot_ros.core.common import SIDE, default_rig, rig_from_params
    from tlessbot_ros.io.config import default_config_path, load_ros_params

    path = config or default_config_path()
    if config is None and (path is None or not Path(path).is_file()):
        return default_rig()[SIDE]
    try:
        rig = rig_from_params(load_ros_params(path, 'pose_estimator'))
    except (ValueError, KeyError, OSError):
        if config is not None:
            raise TlessbotError(f'no usable rig in {config}') from None
        return default_rig()[SIDE]
    return rig[SIDE]


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from tlessbot_ros.core.pose import TemplateParams, build_database
    from tlessbot_ros.io.models import load_models, stable_poses

    try:
        params = TemplateParams(n_views=args.views, max_stable_poses=args.stable_poses,
                                voxel_fraction=args.voxel_fraction, seed=args.seed)
    except ValueError as error:
        raise TlessbotError(str(error)) from None
    models = load_models(args.models, ids=args.ids)
    side = _side_camera(args.config)
    start = time.perf_counter()
    items = [(i, m.vertices, m.faces,
              [(p.T_table_object, p.probability) for p in stable_poses(m, merge_rolling=True)],
              m.diameter_m) for i, m in sorted(models.items())]
    db = build_database(items, intrinsics=side.intrinsics, T_world_camera=side.T_world_camera,
                        params=params, progress=lambda it: tqdm(it, desc='templates',
                                                                unit='obj'),
                        symmetries={i: m.listed_symmetries() for i, m in models.items()})
    db.save(args.out)
    count = sum(len(o.templates) for o in db.objects.values())
    print(f'{len(db.objects)} objects, {count} templates -> {args.out} '
          f'({time.perf_counter() - start:.1f} s)')
    return 0
