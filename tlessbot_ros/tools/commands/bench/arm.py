"""The arm's side end to end: names that hold, poses from TF, request-to-answer latency.

A scripted simulated table (parts rest, then one moves, one goes, one comes) is replayed
through the whole graph (``tlessbot launch``) while an arm-like client (``tlessbot objects``,
its own process) asks GetObjects every ``--interval`` seconds; prints every figure and, with
``--json``, writes them. Goal: request-to-answer p95 <= 1.5 x (sum of the stages' median
latencies + one camera frame period), all measured in the same run.

    tlessbot bench arm --models ../shared/data/tless_models_cad_stl --out /tmp/arm
"""
from __future__ import annotations

import argparse
import json
import tempfile
from dataclasses import asdict
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--models', required=True, type=Path, help='folder of obj_NN models')
    parser.add_argument('--out', type=Path, help='folder for the bag, the log and arm.json')
    parser.add_argument('--ids', type=int, nargs='+', default=[5, 6, 19])
    parser.add_argument('--rest-frames', type=int, default=8)
    parser.add_argument('--change-frames', type=int, default=8)
    parser.add_argument('--fps', type=float, default=2.0, help='bag frame rate')
    parser.add_argument('--rate', type=float, default=0.5, help='replay rate')
    parser.add_argument('--interval', type=float, default=0.2, help='seconds between requests')
    parser.add_argument('--seed', type=int, default=1)


def run(args: argparse.Namespace) -> int:
    from tlessbot_ros.tools.support.arm_trial import (
        ArmTrialParams,
        run_graph_and_client,
        score,
        write_trial_bag,
    )

    params = ArmTrialParams(ids=tuple(args.ids), rest_frames=args.rest_frames,
                            change_frames=args.change_frames, fps=args.fps, rate=args.rate,
                            request_interval_s=args.interval, seed=args.seed)
    out = args.out or Path(tempfile.mkdtemp(prefix='tlessbot_arm_'))
    out.mkdir(parents=True, exist_ok=True)
    truth = write_trial_bag(args.models, out / 'bag', params)
    print(f'bag {out / "bag"}: {params.rest_frames} + {params.change_frames} frames; moved '
          f'{truth.moved}, removed {truth.removed}, added {truth.added}', flush=True)
    answers, diagnostics = run_graph_and_client(out / 'bag', params, log=out / 'launch.log')
    figures = score(answers, truth, diagnostics)
    (out / 'arm.json').write_text(json.dumps({'params': asdict(params), **figures}, indent=1))
    print(f'requests {figures["requests"]}, answered {figures["answered"]} '
          f'(rest / change {figures["answered_per_layout"]})')
    print(f'parts reported {figures["parts_reported"]}, outside 5 cm / 5 deg '
          f'{figures["parts_outside_tolerance"]}, missing {figures["parts_missing"]}, max error '
          f'{figures["max_error_m"] * 100:.1f} cm / {figures["max_error_deg"]:.1f} deg')
    print(f'name swaps while resting {figures["name_swaps"]}, kept parts renamed '
          f'{figures["kept_parts_renamed"]}, new parts with old names '
          f'{figures["new_parts_with_old_names"]}; instances at the end '
          f'{figures["instances_at_end"]} (parts on the table {figures["parts_at_end"]})')
    stages = ' + '.join(f'{s} {v:.0f}' for s, v in figures['stage_p50_ms'].items())
    print(f'request to answer: p50 {figures["latency_p50_s"] * 1e3:.0f} ms, p95 '
          f'{figures["latency_p95_s"] * 1e3:.0f} ms; budget = stages p50 ({stages} ms) + frame '
          f'period {figures["frame_period_s"] * 1e3:.0f} ms = {figures["budget_s"] * 1e3:.0f} ms;'
          f' p95 / budget = {figures["p95_over_budget"]:.2f} (goal <= 1.5)')
    print(f'figures: {out / "arm.json"}')
    return 0
