"""Record one part on the table or a turntable with the cell's cameras, labelled for training.

Records each camera's colour image, aligned depth and both camera_infos (the drivers' topics,
``/NAME/color/image_raw`` ...) into a rosbag2 folder, and writes ``capture.yaml`` beside the
bag's metadata: the part's name and id, the cameras and, per whole frame (every topic of every
camera with one stamp), its stamp and (with --turntable-deg-per-s) the plate angle. Works with
the camera drivers or any publisher of those topics:

    tlessbot capture --part obj_05 --out captures/obj_05 --frames 360 --turntable-deg-per-s 6

Without hardware, --simulate renders the session in the simulated cell (the part on a
turntable, see tlessbot_ros.sim.capture) into the same kind of folder:

    tlessbot capture --simulate --models ../shared/data/tless_models_cad_stl --part obj_05 \\
        --out captures/obj_05 --frames 90 --step-deg 4

Train on the bags: tlessbot train --captures captures/obj_* [--models DIR] --out model.npz
"""
from __future__ import annotations

import argparse
from pathlib import Path

from tlessbot_ros.errors import BagError, TlessbotError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--part', required=True, help="the part's name, e.g. obj_05")
    parser.add_argument('--obj-id', type=int,
                        help='its id in the classifier (default: NN of a name obj_NN)')
    parser.add_argument('--out', type=Path, required=True,
                        help='output bag folder (must not exist)')
    parser.add_argument('--cameras', nargs='+', default=['top', 'side'],
                        help='camera namespaces to record (default: top side)')
    parser.add_argument('--frames', type=int, default=0,
                        help='stop after this many whole frames (every topic of every camera '
                             'with one stamp; default: --duration, or Ctrl-C; --simulate: 90)')
    parser.add_argument('--duration', type=float, default=0.0, metavar='S',
                        help='stop after S seconds (default: --frames, or Ctrl-C)')
    parser.add_argument('--turntable-deg-per-s', type=float, metavar='W',
                        help='the plate turns at W degrees per second: label each frame with '
                             'its angle (from its stamp; the first frame is 0)')
    parser.add_argument('--background', type=Path, metavar='BAG',
                        help='a bag of the empty table with the same cameras, for the '
                             'localiser (stored in the label)')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3'), default='mcap')
    parser.add_argument('--discovery-timeout', type=float, default=5.0, metavar='S')
    sim = parser.add_argument_group('simulated session (--simulate)')
    sim.add_argument('--simulate', action='store_true',
                     help='render the session in the simulated cell instead of recording')
    sim.add_argument('--models', type=Path, help='CAD models folder (with --simulate)')
    sim.add_argument('--step-deg', type=float, default=4.0,
                     help='plate rotation per frame in degrees (default 4)')
    sim.add_argument('--positions', type=int, default=4,
                     help='places of the part on the plate over the session (default 4)')
    sim.add_argument('--seed', type=int, default=0, help='simulator seed (default 0)')
    sim.add_argument('--with-background', action='store_true',
                     help='also render the empty table into OUT/background (in the label)')
    sim.add_argument('--config', type=Path, help='the cell YAML (rig; default config/cell.yaml)')


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.io.capture import part_id

    if args.out.exists():
        raise BagError(f'output {args.out} exists; choose a new folder')
    if args.frames < 0 or args.duration < 0:
        raise TlessbotError('--frames and --duration must not be negative')
    obj_id = args.obj_id if args.obj_id is not None else part_id(args.part)
    label = _simulate(args, obj_id) if args.simulate else _record(args, obj_id)
    if args.background is not None:
        label.background = str(args.background.resolve())
    path = label.write(args.out)
    print(f'captured {args.part} (id {obj_id}): {len(label.frames)} frames of '
          f'{", ".join(label.cameras)} into {args.out}; label {path}')
    return 0


def _simulate(args: argparse.Namespace, obj_id: int):
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.capture import CaptureSessionParams, write_capture_bag
    from tlessbot_ros.sim.simulator import Simulator
    from tlessbot_ros.tools.support.rig import load_rig

    if args.models is None:
        raise TlessbotError('--simulate needs --models DIR')
    try:
        params = CaptureSessionParams(frames=args.frames or 90, step_deg=args.step_deg,
                                      positions=args.positions)
    except ValueError as error:
        raise TlessbotError(str(error)) from None
    rig = load_rig(args.config)
    missing = sorted(set(args.cameras) - set(rig.cameras))
    if missing:
        raise TlessbotError(f'cameras {missing} are not in the rig {sorted(rig.cameras)}')
    rig = type(rig)(cameras={c: rig[c] for c in args.cameras}, world_frame=rig.world_frame)
    models = load_models(args.models, [obj_id])
    if obj_id not in models:
        raise TlessbotError(f'no model of {args.part} (id {obj_id}) in {args.models}')
    return write_capture_bag(Simulator(models, rig=rig, seed=args.seed), obj_id, args.out,
                             part=args.part, params=params, seed=args.seed,
                             with_background=args.with_background, progress=True)


def _record(args: argparse.Namespace, obj_id: int):
    from tqdm import tqdm

    from tlessbot_ros.conversions.cdr import header_stamp_ns
    from tlessbot_ros.conversions.topics import (
        COLOR,
        COLOR_INFO,
        DEPTH,
        DEPTH_INFO,
        camera_topic,
    )
    from tlessbot_ros.io.capture import CaptureLabel
    from tlessbot_ros.tools.commands.record import record

    topics = [camera_topic(c, kind) for c in args.cameras
              for kind in (COLOR, COLOR_INFO, DEPTH, DEPTH_INFO)]
    seen: dict[int, set[str]] = {}   # stamp -> the topics that have brought it
    stamps: list[int] = []           # the stamps whose every topic has been recorded
    bar = tqdm(total=args.frames or None, desc=f'capture {args.part}', unit='frame')

    def on_message(topic: str, raw: bytes) -> None:
        try:
            stamp = header_stamp_ns(raw)
        except ValueError:
            return   # a broken message is recorded as it came, but completes no frame
        topics_seen = seen.setdefault(stamp, set())
        topics_seen.add(topic)
        if len(topics_seen) == len(topics):
            stamps.append(stamp)
            del seen[stamp]
            bar.update()

    try:
        record(topics, args.out, storage=args.storage, duration_s=args.duration,
               discovery_timeout_s=args.discovery_timeout, on_message=on_message,
               until=(lambda: len(stamps) >= args.frames) if args.frames else None)
    finally:
        bar.close()
    stamps.sort()
    rate = args.turntable_deg_per_s
    frames = [{'stamp_ns': s, 'turntable_deg': None if rate is None else
               (rate * (s - stamps[0]) * 1e-9) % 360.0} for s in stamps]
    return CaptureLabel(part=args.part, obj_id=obj_id, cameras=list(args.cameras),
                        frames=frames)
