"""Your own parts: build a parts folder from CAD files, or generate example CAD parts.

    tlessbot parts build --models MY_CAD --out my_parts [--units m] [--config my_cell.yaml]
    tlessbot parts observe --models MY_CAD    # which 5° turns the rig cannot see (seconds)
    tlessbot parts generate --out my_cad      # 8 example parts (plates, brackets, a tube), STL
    tlessbot parts generate --out held_out --seed 7 --count 8   # parts drawn from a seed

build reads every STL / PLY / OBJ of --models (millimetres, or --units m; any file names, each
stem a valid ROS name: it names the part's topic /objects/<stem>/pose) and writes into --out
the classifier (train --recipe hybrid by default), the templates for the rig's side camera,
the models with their info (diameters, symmetries) and manifest.json (name, id, size, symmetry,
look-alikes, the rig); a classifier trained before from the same CAD files and settings is
reused (--retrain: train anew). It ends with a self-check: simulated scenes of the parts seen
by the rig, evaluated, one row per part (self_check.md). Run the graph on it with
``tlessbot launch --parts my_parts`` (or ``parts_path:`` in the cell YAML).
"""
from __future__ import annotations

import argparse
import signal
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from tlessbot_ros.sim.noise import DEPTH_KINDS
    from tlessbot_ros.tools.commands.train import RECIPE_CHOICES
    from tlessbot_ros.tools.support.parts_build import (
        CHECK_FRAMES,
        DEFAULT_RECIPE,
        BuildOptions,
    )

    sub = parser.add_subparsers(dest='action', required=True, metavar='ACTION')
    build = sub.add_parser('build', help='CAD folder -> parts folder',
                           description='Build a parts folder from a folder of CAD files '
                           '(what it writes: tlessbot parts --help; docs/parts.md).')
    build.add_argument('--models', type=Path, required=True,
                       help='folder of STL / PLY / OBJ files, one part each')
    build.add_argument('--out', type=Path, required=True, help='parts folder to write')
    build.add_argument('--units', choices=('mm', 'm'), default='mm',
                       help='units of every file of --models (default mm)')
    build.add_argument('--config', type=Path, help='the cell YAML whose rig the parts are '
                       'seen by (default config/cell.yaml)')
    build.add_argument('--recipe', default=DEFAULT_RECIPE,   # refused here, not minutes on
                       choices=(*RECIPE_CHOICES, 'defaults'),
                       help=f"classifier recipe of tlessbot train (default {DEFAULT_RECIPE}; "
                            "'defaults': train's own defaults)")
    build.add_argument('--check-frames', type=int, default=CHECK_FRAMES,
                       help=f'simulated frames of the self-check (default {CHECK_FRAMES}; 0: '
                            'none)')
    build.add_argument('--check-depth', choices=DEPTH_KINDS, default='per_pixel',
                       help="the self-check's simulated depth: per_pixel (default) or smoothed, "
                            'stereo-like as a real RealSense gives it')
    build.add_argument('--seed', type=int, default=0,
                       help="seed of the classifier's training and the self-check's scenes "
                            '(default 0)')
    build.add_argument('--smoothed-share', type=float, default=BuildOptions.smoothed_share,
                       metavar='F', help="share (0-1) of the classifier's training views and "
                       "scenes with the stereo-like depth a real RealSense gives (train "
                       f'--smoothed-share; default {BuildOptions.smoothed_share:g})')
    build.add_argument('--retrain', action='store_true',
                       help='train the classifier even if one was trained before from the '
                            'same CAD files and settings (kept in the start-up cache)')
    build.add_argument('--train-arg', action='append', default=[], metavar='ARG',
                       help='pass ARG on to tlessbot train (repeatable; --train-arg=--scenes='
                            '200)')
    observe = sub.add_parser('observe', help="which 5° turns of each part the rig's "
                             'cameras cannot see (the build does it too)')
    observe.add_argument('--models', type=Path, required=True,
                         help='folder of STL / PLY / OBJ files, one part each')
    observe.add_argument('--units', choices=('mm', 'm'), default='mm',
                         help="the CAD files' units (default mm)")
    observe.add_argument('--config', type=Path, help='the cell YAML whose rig sees the parts '
                         '(default config/cell.yaml)')
    generate = sub.add_parser('generate', help='write example CAD parts (STL, mm)')
    generate.add_argument('--out', type=Path, required=True, help='folder to write')
    generate.add_argument('--names', nargs='+', help='only these parts')
    generate.add_argument('--seed', type=int, help='draw a family of parts from this seed '
                          '(random sizes, holes, look-alike pairs) instead of the fixed 8')
    generate.add_argument('--count', type=int, default=8,
                          help='parts drawn with --seed (1 to 26, default 8)')


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.errors import TlessbotError

    if args.action == 'generate':
        from tlessbot_ros.tools.support.part_family import family, generate_family
        from tlessbot_ros.tools.support.part_generator import generate_parts, part_shapes

        if not 1 <= args.count <= 26:
            raise TlessbotError(f'--count must be 1 to 26, got {args.count}')
        if args.seed is None and args.count != 8:
            raise TlessbotError('--count needs --seed (the fixed example parts are 8)')
        known = sorted(part_shapes() if args.seed is None else family(args.seed, args.count))
        unknown = sorted(set(args.names or ()) - set(known))
        if unknown:
            raise TlessbotError(f'no generated part {unknown}; choose from {known}')
        paths = generate_parts(args.out, args.names) if args.seed is None else \
            generate_family(args.out, args.seed, args.count, args.names)
        print(f'{len(paths)} parts -> {args.out}: {", ".join(p.stem for p in paths)}')
        return 0
    from tlessbot_ros.tools.support.parts_build import BuildOptions, build_parts, observe_parts

    if args.action == 'observe':
        print(observe_parts(args.models, BuildOptions(units=args.units, config=args.config)))
        return 0
    if args.check_frames < 0:
        raise TlessbotError('--check-frames must be >= 0')
    if not 0.0 <= args.smoothed_share <= 1.0:
        raise TlessbotError(f'--smoothed-share must be in [0, 1], got {args.smoothed_share}')
    options = BuildOptions(units=args.units, config=args.config,
                           recipe=None if args.recipe == 'defaults' else args.recipe,
                           check_frames=args.check_frames, check_depth=args.check_depth,
                           seed=args.seed, smoothed_share=args.smoothed_share,
                           train_args=args.train_arg, reuse_classifier=not args.retrain)
    # SIGTERM (kill, timeout) as Ctrl-C: the half-built folder is removed, the children end
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        build_parts(args.models, args.out, options, check=args.check_frames > 0)
    finally:
        signal.signal(signal.SIGTERM, previous)
    return 0


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt
