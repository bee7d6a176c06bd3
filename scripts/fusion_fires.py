"""On which frames a localiser setting changes the fused side regions (the localiser alone).

    python scripts/fusion_fires.py SCENES PARTS SEED:SET... --base NAME=VALUE... \
        [--rule NAME=VALUE ...]

SCENES: a scenes folder of the bench (SCENES/SEED-SET, top and side splits); PARTS: its parts
folder (PARTS/SET with templates.npz and classifier.npz; T-LESS, SET ``T``, reads the
package's own). Every frame is localised with ``--base`` (e.g. the rules off: main's
behaviour), with the defaults, and with ``--base`` less each ``--rule`` (that rule at the
value given, the others as in ``--base``). A frame *fires* when the side labels divide the
pixels otherwise (ids may differ). One line per cell: the frames each setting fires on.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import SIDE, TOP, CameraMount, Rig
from tlessbot_ros.core.pipeline import PerceptionPipeline, ViewInput
from tlessbot_ros.core.pose import TemplateDatabase
from tlessbot_ros.core.recognise import LinearClassifier
from tlessbot_ros.io.bop import read_split
from tlessbot_ros.tools.support.overrides import stage_overrides

PACKAGE_PARTS = Path(__file__).resolve().parents[1] / 'tlessbot_ros' / 'data'


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two label images divide the pixels alike (whatever their ids)."""
    a, b = a.ravel().astype(np.int64), b.ravel().astype(np.int64)
    pairs = np.unique(a * 65536 + b).size
    return pairs == np.unique(a).size == np.unique(b).size


def _settings(base: list[str], rules: list[str]) -> dict[str, list[str]]:
    out = {'defaults': []}
    for rule in rules:
        name = rule.partition('=')[0]
        out[name] = [a for a in base if a.partition('=')[0] != name] + [rule]
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('scenes', type=Path)
    ap.add_argument('parts', type=Path)
    ap.add_argument('cells', nargs='+', metavar='SEED:SET')
    ap.add_argument('--base', nargs='+', default=[], metavar='NAME=VALUE')
    ap.add_argument('--rule', action='append', default=[], metavar='NAME=VALUE')
    args = ap.parse_args()
    settings = _settings(args.base, args.rule)
    for cell in args.cells:
        seed, name = cell.split(':')
        parts = PACKAGE_PARTS if name == 'T' else args.parts / name
        database = TemplateDatabase.load(parts / 'templates.npz')
        model = LinearClassifier.load(parts / 'classifier.npz')
        base: PerceptionPipeline | None = None
        pipelines: dict[str, PerceptionPipeline] = {}
        fires: dict[str, list[int]] = {k: [] for k in settings}
        readers = [read_split(args.scenes / f'{seed}-{name}', f'test_{v}') for v in (TOP, SIDE)]
        for top, side in zip(*readers):
            by_view = {TOP: top, SIDE: side}
            if base is None:
                rig = Rig({v: CameraMount(v, im.intrinsics, im.T_world_camera)
                           for v, im in by_view.items()})
                base = PerceptionPipeline(rig=rig, classifier=model, templates=database,
                                          **stage_overrides(args.base))
                pipelines = {k: PerceptionPipeline(rig=rig, classifier=model,
                                                   templates=database, **stage_overrides(a))
                             for k, a in settings.items()}
            views = {v: ViewInput(im.rgb, im.depth_m, im.intrinsics, im.T_world_camera)
                     for v, im in by_view.items()}
            before = base.localise(views).labels[SIDE]
            for k, pipeline in pipelines.items():
                if not same_partition(before, pipeline.localise(views).labels[SIDE]):
                    fires[k].append(side.im_id)
        print(cell, args.scenes.name, json.dumps(fires), flush=True)


if __name__ == '__main__':
    main()
