"""When the pose stage hands out its first pose, as a share of the stage's CPU time per frame.

    PYTHONPATH=TREE python scripts/first_pose_share.py OUT.json evaluate --dataset D ... --limit 10

Runs ``tlessbot evaluate`` (the arguments after OUT.json) with ``estimate_poses`` wrapped: per
frame, the process CPU time from the stage's start to the first pose handed to
``on_detection`` (what the pose node publishes at once), the mean over all poses handed out,
and the stage's total. Prints the median and mean of first / total and of the mean hand-out /
total, shares that hold on any host. Compare two trees on the same frames (one run each).
"""
from __future__ import annotations

import json
import statistics
import sys
import time

from tlessbot_ros.core import pipeline as pipeline_module

_estimate = pipeline_module.PerceptionPipeline.estimate_poses
rows: list[dict[str, float | None]] = []


def _timed(self, views, labels, classes, *, box_mode=False, on_detection=None, fitter=None):
    start, handed = time.process_time(), []

    def hook(detection):
        if detection.pose is not None:
            handed.append(time.process_time() - start)
        if on_detection is not None:
            on_detection(detection)

    out = _estimate(self, views, labels, classes, box_mode=box_mode, on_detection=hook,
                    fitter=fitter)
    rows.append({'first_s': handed[0] if handed else None,
                 'mean_s': statistics.mean(handed) if handed else None,
                 'total_s': time.process_time() - start})
    return out


def main() -> None:
    pipeline_module.PerceptionPipeline.estimate_poses = _timed   # type: ignore[method-assign]
    from tlessbot_ros.tools.cli import main as cli_main
    try:
        cli_main(sys.argv[2:])
    finally:
        with open(sys.argv[1], 'w') as out:
            json.dump(rows, out, indent=1)
    posed = [r for r in rows if r['first_s'] is not None and r['total_s']]
    first = [r['first_s'] / r['total_s'] for r in posed]
    mean = [r['mean_s'] / r['total_s'] for r in posed]
    print(f'{len(posed)} frames with a pose: first pose at {statistics.median(first):.2f} of the '
          f'stage (median; mean {statistics.mean(first):.2f}), poses on average at '
          f'{statistics.mean(mean):.2f}')


if __name__ == '__main__':
    main()
