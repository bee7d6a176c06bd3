"""Write a BOP models_info.json (diameter, size, symmetries) for a folder of CAD models.

    tlessbot models-info --models ../shared/data/tless_models_cad_stl --out models_info.json

Symmetries come from the folder's own models_info.json when it has one, else they are detected
from the mesh (core.symmetry.detect_symmetries); ``tlessbot simulate`` writes the same
entries. Units are millimetres, as in BOP.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from tlessbot_ros.io.models import load_models
from tlessbot_ros.tools.support.models_info import model_symmetries, models_info_entry


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', required=True, help='folder of CAD models (mm)')
    parser.add_argument('--out', required=True, help='models_info.json to write')
    parser.add_argument('--ids', type=int, nargs='+', default=None, help='only these ids')


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    models = load_models(args.models, ids=args.ids)
    info = {}
    for obj_id, model in tqdm(sorted(models.items()), desc='symmetries', unit='obj'):
        symmetries = model_symmetries(model)
        info[str(obj_id)] = models_info_entry(model, symmetries)
        tqdm.write(f'obj_{obj_id:02d}: {symmetries.describe()}')
    Path(args.out).write_text(json.dumps(info, indent=1) + '\n')
    print(f'{len(info)} models -> {args.out}')
    return 0
