"""The arm's trial: a scripted table (parts rest, then one moves, one goes, one comes) replayed
through the whole graph while an arm-like client process asks GetObjects again and again and
composes each part's world pose from /tf_static and /tf; then every answer is scored against
the ground truth: pose error, name swaps while parts rest, new names only for moved or new
parts, removed parts gone after the time to live, and request-to-answer latency against the
stages' own medians in the same run.

Used by ``tlessbot bench arm`` (figures) and test/e2e/test_arm.py (assertions).
"""
from __future__ import annotations

import json
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tlessbot_ros.core.common import part_name
from tlessbot_ros.core.track import nearest_equivalent

STAGES = ('localiser', 'classifier', 'pose_estimator')


@dataclass(frozen=True)
class ArmTrialParams:
    ids: tuple[int, ...] = (5, 6, 19)
    parts: int = 4
    rest_frames: int = 8
    change_frames: int = 8
    fps: float = 2.0
    rate: float = 0.5
    ttl_s: float = 1.5
    seed: int = 1
    request_interval_s: float = 0.2
    request_timeout_s: float = 4.0
    tolerance_m: float = 0.05
    tolerance_deg: float = 5.0


@dataclass
class GroundTruth:
    """Per layout: [(key, part name, T_world_part)]; keys moved / removed / added."""

    layouts: list[list[tuple[str, str, np.ndarray]]]
    moved: list[str]
    removed: list[str]
    added: list[str]
    start_ns: int
    params: ArmTrialParams
    symmetries: dict[str, np.ndarray] = field(default_factory=dict)

    def layout_of(self, stamp_ns: int) -> int:
        index = round((stamp_ns - self.start_ns) * self.params.fps / 1e9)
        return 0 if index < self.params.rest_frames else 1


def write_trial_bag(models_dir: Path, bag: Path, params: ArmTrialParams) -> GroundTruth:
    """Simulate the scripted table into ``bag``; its ground truth in the world."""
    from tlessbot_ros.io.models import load_models
    from tlessbot_ros.sim.bag import BagParams, write_bag
    from tlessbot_ros.sim.script import ScriptParams, script_frames, scripted_table
    from tlessbot_ros.sim.simulator import Simulator
    from tlessbot_ros.tools.support.models_info import packaged_symmetries
    from tlessbot_ros.tools.support.rig import load_rig

    sim = Simulator(load_models(models_dir, list(params.ids)), rig=load_rig(None),
                    seed=params.seed)
    script = ScriptParams(rest_frames=params.rest_frames, change_frames=params.change_frames,
                          parts=params.parts)
    table = scripted_table(sim, script, seed=params.seed)
    bag_params = BagParams(fps=params.fps, cloud_stride=4)
    write_bag(script_frames(sim, table, script), bag, params=bag_params)
    layouts = [[(key, part_name(o.obj_id), o.T_world_object) for key, o in zip(keys, layout)]
               for keys, layout in zip(table.keys, table.layouts)]
    symmetries = {part_name(i): s.transforms(step_rad=np.radians(2.0))
                  for i, s in packaged_symmetries().items() if i in params.ids}
    return GroundTruth(layouts, table.moved, table.removed, table.added, bag_params.start_ns,
                       params, symmetries)


class _Diagnostics:
    """The latest /diagnostics values per status name, in a background rclpy node."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor

        self.values: dict[str, dict[str, str]] = {}
        self._context = rclpy.Context()
        rclpy.init(context=self._context)
        self._node = rclpy.create_node('arm_trial_diagnostics', context=self._context)
        self._node.create_subscription(DiagnosticArray, '/diagnostics', self._on, 50)
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _on(self, msg: Any) -> None:
        for status in msg.status:
            self.values[status.name] = {kv.key: kv.value for kv in status.values}

    def _spin(self) -> None:
        while not self._stop.is_set():
            self._executor.spin_once(timeout_sec=0.1)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self._executor.shutdown(timeout_sec=1.0)
        self._node.destroy_node()
        self._context.try_shutdown()


def run_graph_and_client(bag: Path, params: ArmTrialParams, *, log: Path,
                         ready_timeout_s: float = 900.0) -> tuple[list[dict], dict]:
    """Launch the graph on ``bag`` and the arm client (``tlessbot objects``), each in its own
    process; returns the client's answers and the last /diagnostics values per node."""
    import subprocess

    from tlessbot_ros.tools.support.processes import same_code_env

    env = same_code_env()
    cli = [sys.executable, '-m', 'tlessbot_ros.tools.cli']
    diagnostics = _Diagnostics()
    with open(log, 'w') as out:
        launch = subprocess.Popen(
            [*cli, 'launch', '--replay', str(bag), '--rate', str(params.rate),
             '-p', f'track.ttl_s:={params.ttl_s}'], stdout=out, stderr=subprocess.STDOUT,
            env=env, start_new_session=True)
        try:
            client = subprocess.run(
                [*cli, 'objects', '--count', '0', '--json', '--interval',
                 str(params.request_interval_s), '--timeout', str(params.request_timeout_s),
                 '--stop-after-failures', '3', '--wait-for-service', '120'],
                capture_output=True, text=True, env=env, timeout=ready_timeout_s)
        finally:
            time.sleep(2.0)   # the last diagnostics
            launch.send_signal(2)
            try:
                launch.wait(60)
            except subprocess.TimeoutExpired:
                launch.kill()
            diagnostics.close()
    answers = [json.loads(line) for line in client.stdout.splitlines() if line.startswith('{')]
    return answers, diagnostics.values


def score(answers: list[dict], truth: GroundTruth, diagnostics: dict[str, dict[str, str]]
          ) -> dict[str, Any]:
    """Every figure of the trial (see the module docstring)."""
    p = truth.params
    answered = [a for a in answers if a['success']]
    names: dict[tuple[int, str], list[str]] = {}
    errors_m, errors_deg, wrong, missing, unmatched, tf_gaps = [], [], 0, 0, 0, 0
    for answer in answered:
        layout = truth.layout_of(answer['stamp_ns'])
        found = {}
        for part in answer['parts']:
            T = np.array(part['T_world_part_tf'] if part['T_world_part_tf'] is not None
                         else part['T_frame_part'])
            tf_gaps += part['T_world_part_tf'] is None
            candidates = [(np.linalg.norm(T[:3, 3] - T_gt[:3, 3]), key, T_gt)
                          for key, name, T_gt in truth.layouts[layout] if name == part['part']
                          and key not in found]
            if not candidates:
                unmatched += 1
                continue
            distance, key, T_gt = min(candidates, key=lambda c: c[0])
            _, angle = nearest_equivalent(T, T_gt, truth.symmetries.get(part['part']))
            found[key] = part['instance']
            errors_m.append(distance)
            errors_deg.append(angle)
            wrong += distance > p.tolerance_m or angle > p.tolerance_deg
            names.setdefault((layout, key), []).append(part['instance'])
        missing += len(truth.layouts[layout]) - len(found)
    swaps = sum(sum(a != b for a, b in zip(seq, seq[1:])) for seq in names.values())
    rest_names = {n for (layout, _), seq in names.items() if layout == 0 for n in seq}
    kept = [k for k, _, _ in truth.layouts[1] if k in {k0 for k0, _, _ in truth.layouts[0]}]
    kept_wrong = sum(names.get((1, k), [None])[0] not in set(names.get((0, k), [])) for k in kept
                     if (1, k) in names)
    new_keys = [k for k, _, _ in truth.layouts[1] if k not in kept]
    reused = sum(n in rest_names for k in new_keys for n in names.get((1, k), []))
    latencies = np.array([a['latency_s'] for a in answered]) if answered else np.zeros(1)
    stage_ms = {s: float(diagnostics.get(s, {}).get('latency_ms_p50', 'nan')) for s in STAGES}
    budget_s = sum(stage_ms.values()) / 1e3 + 1.0 / (p.fps * p.rate)
    return {
        'requests': len(answers), 'answered': len(answered),
        'answered_per_layout': [sum(truth.layout_of(a['stamp_ns']) == k for a in answered)
                                for k in (0, 1)],
        'parts_reported': len(errors_m), 'parts_missing': missing,
        'parts_unmatched': unmatched, 'parts_outside_tolerance': wrong,
        'tf_missing': tf_gaps,
        'max_error_m': float(max(errors_m, default=0.0)),
        'max_error_deg': float(max(errors_deg, default=0.0)),
        'name_swaps': swaps, 'kept_parts_renamed': kept_wrong,
        'new_parts_with_old_names': reused,
        'names': {f'{layout}:{key}': sorted(set(seq)) for (layout, key), seq in names.items()},
        'instances_at_end': int(diagnostics.get('objects', {}).get('instances', -1)),
        'parts_at_end': len(truth.layouts[1]),
        'latency_p50_s': float(np.percentile(latencies, 50)),
        'latency_p95_s': float(np.percentile(latencies, 95)),
        'stage_p50_ms': stage_ms, 'frame_period_s': 1.0 / (p.fps * p.rate),
        'budget_s': budget_s,
        'p95_over_budget': float(np.percentile(latencies, 95)) / budget_s,
    }
