"""cProfile (or line_profiler) of the three stages' process() on a bag's frames.

    PYTHONPATH=$PWD python test/tools/profile_stages.py [--bag bags/demo] [--passes 3]
        [--out DIR] [--lines module:function,module:Class.method,...]

The frames go through LocaliserNode, ClassifierNode and PoseEstimatorNode in-process as
``tlessbot bench nodes`` feeds them, with ``parallel_views`` off and ``workers.count`` 0 so
that all the work runs on the profiled thread. Writes ``DIR/{localiser,classifier,pose}.prof``
and ``.txt`` (cumulative order), or with ``--lines`` (line_profiler, installed outside the
project's venv: ``pip install --target /tmp/prof line_profiler`` and ``PYTHONPATH=$PWD:/tmp/prof``)
``DIR/lines.txt``; prints each stage's CPU ms per frame (profiler overhead included).
"""
from __future__ import annotations

import argparse
import cProfile
import importlib
import io
import os
import pstats
import sys
import time


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--bag', default=None)
    parser.add_argument('--passes', type=int, default=3)
    parser.add_argument('--out', default='profile')
    parser.add_argument('--lines', default='', help='functions for line_profiler')
    args = parser.parse_args()

    import rclpy
    from rclpy.parameter import Parameter

    from tlessbot_ros.conversions.image_cdr import image_from_cdr
    from tlessbot_ros.core.common import CAMERA_NAMES
    from tlessbot_ros.nodes.classifier import ClassifierNode
    from tlessbot_ros.nodes.common import init_ros, limit_blas_threads
    from tlessbot_ros.nodes.localiser import LocaliserNode
    from tlessbot_ros.nodes.pose_estimator import PoseEstimatorNode
    from tlessbot_ros.tools.commands.bench.nodes import _Captured, bag_frames
    from tlessbot_ros.tools.support.defaults import DEFAULT_BAG

    frames = bag_frames(args.bag or str(DEFAULT_BAG))
    limit_blas_threads()
    init_ros()
    lines = None
    if args.lines:
        from line_profiler import LineProfiler

        lines = LineProfiler()
        for spec in args.lines.split(','):
            module, name = spec.split(':')
            target = importlib.import_module(module)
            for part in name.split('.'):
                target = getattr(target, part)
            lines.add_function(target)
    try:
        stages = {
            'localiser': LocaliserNode(parameter_overrides=[
                Parameter('parallel_views', value=False)]),
            'classifier': ClassifierNode(),
            'pose': PoseEstimatorNode(parameter_overrides=[Parameter('workers.count', value=0)])}
        for node in stages.values():
            if not node.wait_ready():
                print(f'{node.get_name()} did not get ready: {node.last_error}')
                return 1
        labels = {c: _Captured() for c in CAMERA_NAMES}
        classes = {c: _Captured() for c in CAMERA_NAMES}
        stages['localiser']._label_publishers = labels
        stages['classifier']._class_publishers = classes
        pose = stages['pose']
        pose._pose_publishers = {k: _Captured() for k in pose._pose_publishers}
        pose._markers, pose._overlay = _Captured(), _Captured()
        profiles = {name: cProfile.Profile() for name in stages}
        cpu_s = dict.fromkeys(stages, 0.0)
        outputs = {'localiser': (labels, 'labels'), 'classifier': (classes, 'classes')}
        for _ in range(max(1, args.passes)):
            for frame in frames:
                views = {c: dict(msgs) for c, msgs in frame.items()}
                for name, node in stages.items():
                    start = time.process_time()
                    profiler = lines if lines is not None else profiles[name]
                    profiler.enable_by_count() if lines is not None else profiler.enable()
                    node.process(views)
                    profiler.disable_by_count() if lines is not None else profiler.disable()
                    cpu_s[name] += time.process_time() - start
                    if name in outputs:
                        published, key = outputs[name]
                        for c in views:
                            views[c][key] = image_from_cdr(published[c].last)
        count = max(1, args.passes) * len(frames)
        print('CPU ms per frame (profiler included): ' + ', '.join(
            f'{name} {1e3 * s / count:.1f}' for name, s in cpu_s.items())
            + f'; load average {os.getloadavg()[0]:.2f}')
        os.makedirs(args.out, exist_ok=True)
        if lines is not None:
            text = io.StringIO()
            lines.print_stats(stream=text, stripzeros=True)
            with open(os.path.join(args.out, 'lines.txt'), 'w') as out:
                out.write(text.getvalue())
        else:
            for name, profile in profiles.items():
                profile.dump_stats(os.path.join(args.out, f'{name}.prof'))
                text = io.StringIO()
                pstats.Stats(profile, stream=text).sort_stats('cumulative').print_stats(70)
                with open(os.path.join(args.out, f'{name}.txt'), 'w') as out:
                    out.write(text.getvalue())
        for node in stages.values():
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
