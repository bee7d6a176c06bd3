"""Render simulated two-view table scenes of CAD parts to a BOP dataset (and/or a rosbag2).

Writes ``<out>/test_top`` and ``<out>/test_side`` (same scene and image ids), ``camera_top.json``,
``camera_side.json`` and ``models_info.json`` (diameters, mm, and the symmetries the models'
folder lists, else detected as ``tlessbot models-info`` does); with ``--backgrounds`` also
``background_top`` / ``background_side``: each frame's empty table (same ids, no ground truth).
The rig comes from the YAML (``config/cell.yaml`` by default); ``--width/--height`` rescale its
intrinsics. ``--cameras side`` writes that camera alone (a cell of one camera), the scenes
unchanged.

Example:
  tlessbot simulate --models ../shared/data/tless_models_cad_stl --out /tmp/sim --frames 20
"""
from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

from tlessbot_ros.errors import DatasetError, TlessbotError
from tlessbot_ros.sim.noise import DEPTH_KINDS
from tlessbot_ros.tools.support.board_calibration import add_board_arguments, board_from_args
from tlessbot_ros.tools.support.models_info import model_symmetries, models_info_entry
from tlessbot_ros.tools.support.rig import load_rig


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', required=True, type=Path,
                        help='folder of obj_NN.stl|ply|obj models (mm) or a BOP models/ folder')
    parser.add_argument('--out', type=Path, help='output BOP dataset folder')
    parser.add_argument('--bag', type=Path, help='also write a rosbag2 (mcap) folder here')
    parser.add_argument('--fps', type=float, default=15.0, help='bag frame rate (default 15)')
    parser.add_argument('--cloud-stride', type=int, default=1,
                        help='bag point clouds use every n-th pixel row and column (default 1)')
    parser.add_argument('--no-compress', action='store_true',
                        help='write the bag without zstd chunk compression')
    parser.add_argument('--frames', type=int, default=10, help='number of frames (default 10)')
    parser.add_argument('--first', type=int, default=0, help='index of the first frame')
    parser.add_argument('--seed', type=int, default=0)
    parser.add_argument('--ids', type=int, nargs='+', help='object ids to use (default: all)')
    parser.add_argument('--parts-min', type=int, default=1)
    parser.add_argument('--parts-max', type=int, default=8)
    parser.add_argument('--width', type=int, help='image width (default: from the config)')
    parser.add_argument('--height', type=int, help='image height (default: from the config)')
    parser.add_argument('--config', type=Path,
                        help='ROS parameter YAML with the rig (default config/cell.yaml)')
    parser.add_argument('--noise-scale', type=float, default=1.0,
                        help='depth noise sigma and dropout multiplier (0 = clean depth)')
    parser.add_argument('--depth-model', choices=DEPTH_KINDS, default='per_pixel',
                        help='depth noise: per_pixel (default) or smoothed, stereo-like as a '
                             'real RealSense gives it (docs/bench/smoothed-sim-depth.md)')
    parser.add_argument('--materials', nargs='+', help='subset of light_yellow pink black blue')
    parser.add_argument('--tables', nargs='+', help='subset of plain wood checker')
    parser.add_argument('--no-masks', action='store_true', help='skip mask_visib/ PNGs')
    parser.add_argument('--lean-prob', type=float, default=0.0,
                        help='chance that a part leans, tilted 15-40 degrees out of its stable '
                             'pose as if propped on a neighbour (tests the pose fallback; '
                             'default 0)')
    parser.add_argument('--pile', action='store_true',
                        help='crowded scenes: every part after the first lies next to one '
                             'already placed, classes drawn with repeats (e.g. with '
                             '--parts-min 12 --parts-max 15; parts are never stacked)')
    parser.add_argument('--backgrounds', action='store_true',
                        help='also write background_<camera> splits: the same table and light '
                             'without parts (for background subtraction), same ids')
    parser.add_argument('--board', action='store_true',
                        help='lay a printed ChArUco board on the table (the --board-* options; '
                             'default the A3 board centred at the world origin), to test '
                             'tlessbot calibrate --board')
    add_board_arguments(parser)
    parser.add_argument('--script', action='store_true',
                        help='one table that changes: --parts-max parts (of --ids) rest for '
                             '--rest-frames, then one moved, one removed, one added for '
                             '--change-frames (tlessbot_ros/sim/script.py; --frames ignored)')
    parser.add_argument('--rest-frames', type=int, default=6, help='--script: first layout')
    parser.add_argument('--change-frames', type=int, default=6, help='--script: second layout')
    parser.add_argument('--cameras', nargs='+', metavar='NAME',
                        help='write only these cameras of the rig, e.g. --cameras side: a bag '
                             'of one camera (the scenes stay those of the whole rig)')
    parser.add_argument('--no-progress', action='store_true')


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    if args.out is None and args.bag is None:
        raise TlessbotError('nothing to write: give --out DIR and/or --bag FILE')
    if args.frames < 1:
        raise TlessbotError('--frames must be at least 1')
    if args.cloud_stride < 1:
        raise TlessbotError('--cloud-stride must be at least 1')
    sim = _simulator(args)
    cameras = list(args.cameras or sim.rig.cameras)
    unknown = sorted(set(cameras) - set(sim.rig.cameras))
    if unknown:
        raise TlessbotError(f'--cameras {" ".join(unknown)}: the rig has the cameras '
                            f'{", ".join(sim.rig.cameras)}')
    writers, backgrounds = _dataset_writers(args, sim, cameras)

    rendered, indices = _frame_source(sim, args)
    bar = tqdm(indices, desc='simulate', unit='frame', disable=args.no_progress)

    short = []

    def frames() -> Iterator:
        for index in bar:
            frame = rendered(index)
            frame = replace(frame, views={name: frame.views[name] for name in cameras})
            if len(frame.objects) < args.parts_min:
                short.append(index)
            for name, writer in writers.items():
                writer.add(frame.scene_id, frame.im_id, frame.views[name])
            if backgrounds:
                empty = sim.empty_table(index)
                for name, writer in backgrounds.items():
                    writer.add(frame.scene_id, frame.im_id, empty[name])
            yield frame

    try:
        if args.bag is not None:
            from tlessbot_ros.sim.bag import BagParams, write_bag

            counts = write_bag(frames(), args.bag, params=BagParams(
                fps=args.fps, cloud_stride=args.cloud_stride, compress=not args.no_compress))
            print(f'bag {args.bag}: ' + ', '.join(f'{t} {n}' for t, n in sorted(counts.items())))
        else:
            for _ in frames():
                pass
    finally:
        for writer in [*writers.values(), *backgrounds.values()]:
            writer.close()
    if short:
        print(f'note: {len(short)} frame(s) hold fewer than --parts-min parts (no free place '
              f'seen by every camera), e.g. frame {short[0]}')
    if args.out is not None:
        print(f'wrote {len(indices)} frames of {len(cameras)} camera(s) to {args.out} '
              f'(splits: {", ".join("test_" + n for n in writers)})')
    return 0


def _simulator(args: argparse.Namespace):
    """The prepared :class:`~tlessbot_ros.sim.simulator.Simulator` the arguments describe."""
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.board import SimBoard
    from tlessbot_ros.sim.materials import MATERIALS, TABLE_KINDS
    from tlessbot_ros.sim.noise import DepthNoiseParams
    from tlessbot_ros.sim.simulator import SimParams, Simulator

    board = None
    if args.board:
        x_m, y_m, yaw_deg = args.board_pose
        board = SimBoard(board_from_args(args), x_m=x_m, y_m=y_m, yaw_deg=yaw_deg)
    try:
        params = SimParams(parts_min=args.parts_min, parts_max=args.parts_max,
                           noise_scale=args.noise_scale,
                           noise=DepthNoiseParams(kind=args.depth_model),
                           materials=tuple(args.materials or MATERIALS),
                           tables=tuple(args.tables or TABLE_KINDS), board=board,
                           lean_prob=args.lean_prob,
                           **({'unique_classes': False, 'cluster_prob': 1.0} if args.pile else {}))
    except ValueError as error:
        raise TlessbotError(str(error)) from None
    models = load_models(args.models, args.ids, progress=not args.no_progress)
    rig = load_rig(args.config, width=args.width, height=args.height)
    sim = Simulator(models, rig=rig, params=params, seed=args.seed)
    sim.prepare(progress=not args.no_progress)
    return sim


def _dataset_writers(args: argparse.Namespace, sim, cameras: list[str]) -> tuple[dict, dict]:
    """The BOP writers of ``--out`` per camera of ``cameras``: the frames' and the empty
    tables' (none without ``--out``); the camera and model files are written here."""
    from tlessbot_ros.io.bop import BopWriter, write_camera_json

    writers, backgrounds = {}, {}
    if args.out is None:
        return writers, backgrounds
    if args.out.exists() and not args.out.is_dir():
        raise DatasetError(f'--out {args.out} exists and is not a folder')
    args.out.mkdir(parents=True, exist_ok=True)
    for name in cameras:
        cam = sim.rig[name]
        writers[name] = BopWriter(args.out, f'test_{name}', write_masks=not args.no_masks)
        if args.backgrounds:
            backgrounds[name] = BopWriter(args.out, f'background_{name}')
        write_camera_json(args.out / f'camera_{name}.json', cam.intrinsics)
    # the models' symmetries too: a tool that scores the dataset (bop_toolkit) reads them here
    (args.out / 'models_info.json').write_text(json.dumps(
        {str(i): models_info_entry(m, model_symmetries(m)) for i, m in sim.models.items()},
        indent=1))
    return writers, backgrounds


def _frame_source(sim, args: argparse.Namespace):
    """(index -> frame, indices): random scenes, or the --script table."""
    if not args.script:
        return sim.frame, range(args.first, args.first + args.frames)
    from tlessbot_ros.sim.script import ScriptParams, scripted_table

    try:
        params = ScriptParams(rest_frames=args.rest_frames, change_frames=args.change_frames,
                              parts=args.parts_max)
        table = scripted_table(sim, params, seed=args.seed)
    except ValueError as error:
        raise TlessbotError(f'--script: {error}') from None
    names = [[f'{k}=obj_{o.obj_id:02d}' for k, o in zip(keys, layout)]
             for keys, layout in zip(table.keys, table.layouts)]
    print(f'script: frames 0-{params.rest_frames - 1}: {" ".join(names[0])}; then moved '
          f'{table.moved}, removed {table.removed}, added {table.added}: {" ".join(names[1])}')

    def render(index: int):
        layout = table.layouts[table.layout_of_frame(index, params)]
        return sim.frame_of(index, layout, environment=0)
    return render, range(params.rest_frames + params.change_frames)
