"""Build the start-up caches (compiled kernels, the pose stage's derived arrays) ahead of time.

    tlessbot warm-up                          # the packaged templates (make setup runs this)
    tlessbot warm-up --templates my.npz

A pose node's first start otherwise compiles the numba kernels (cached by numba next to the
sources) and builds every template's FPFH and every object's nearest-point grid (cached in
~/.cache/tlessbot_ros, see tlessbot_ros/io/cache.py); later starts read both. Safe to run
again: what is cached already is only read.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from tlessbot_ros.data import DEFAULT_TEMPLATES
from tlessbot_ros.errors import ModelFileError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--templates', type=Path, default=DEFAULT_TEMPLATES,
                        help='template database .npz (default: the packaged one)')


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.core.pipeline import PerceptionPipeline
    from tlessbot_ros.core.pose import TemplateDatabase
    from tlessbot_ros.io.cache import warm_pose_stage

    if not args.templates.is_file():
        raise ModelFileError(f'templates file not found: {args.templates}')
    pipeline = PerceptionPipeline(templates=TemplateDatabase.load(args.templates))
    report = warm_pose_stage(pipeline, args.templates)
    where = 'read from the cache' if report.from_cache else \
        (f'built and cached in {report.stored}' if report.stored else
         'built (the cache could not be written)')
    print(f'warm-up: pose stage ready in {report.seconds:.1f} s; derived arrays {where}')
    return 0
