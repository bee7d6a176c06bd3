"""Start the perception graph, every node in its own OS process (like `ros2 launch`).

    tlessbot launch                              # two camera drivers + the perception nodes
    tlessbot launch --replay bags/demo.mcap      # the bag stands in for the cameras
    tlessbot launch --nodes localiser classifier # a subset

Each node gets ``--ros-args --params-file <config>``; output lines are prefixed with the node's
name. Once every stage node reports ready on /diagnostics, launch prints one line
(``[launch] graph ready in 6.2 s (localiser 1.9 s, ...)``); with ``--replay`` the bag starts
only then, so no frame is sent to a node that cannot take it yet. Ctrl-C or SIGTERM is passed
on to every node (as SIGINT). If a node dies, the others are stopped and launch exits
non-zero, naming the node and its exit code.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.support.processes import (
    PERCEPTION_NODES,
    GraphProcesses,
    graph_processes,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--config', default=None,
                        help='parameter YAML (default: config/cell.yaml)')
    parser.add_argument('--replay', default=None, metavar='BAG',
                        help='replay this bag instead of starting the camera drivers')
    parser.add_argument('--rate', type=float, default=1.0, help='replay rate')
    parser.add_argument('--loop', action='store_true', help='replay in a loop')
    parser.add_argument('-p', '--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='parameter override for every node (repeatable), e.g. '
                             '-p templates_path:=my_templates.npz')
    parser.add_argument('--nodes', nargs='+', default=None,
                        help='only these nodes (camera_driver, localiser, classifier, '
                             'pose_estimator)')


def run(args: argparse.Namespace) -> int:
    config = Path(args.config) if args.config else default_config_path()
    if not config.is_file():
        raise TlessbotError(f'parameter file not found: {config}')
    for override in args.param:
        if ':=' not in override:
            raise TlessbotError(f'parameter override must look like NAME:=VALUE, got {override!r}')
    specs = graph_processes(config, replay=args.replay, rate=args.rate, loop=args.loop,
                            nodes=args.nodes,
                            extra_ros_args=[a for o in args.param for a in ('-p', o)])
    # Stop the graph on Ctrl-C and on SIGTERM (systemd, docker stop, kill), never leaving the
    # nodes orphaned; SIGINT is handled even when a shell started launch in the background,
    # which makes it ignore SIGINT.
    from tlessbot_ros.nodes.common import interrupt_on_signals

    interrupt_on_signals()
    replay_specs = [s for s in specs if s.label == 'replay']
    graph = GraphProcesses([s for s in specs if s.label != 'replay'], env=dict(os.environ))
    stages = [s.label for s in graph.specs if s.label in PERCEPTION_NODES]
    monitor = None
    reported: set[str] = set()   # nodes whose failed warm-up was printed
    try:
        graph.start()
        print(f'launched {len(graph.specs)} processes: '
              + ', '.join(s.label for s in graph.specs), flush=True)
        monitor = _readiness_monitor(stages)
        if monitor is None:   # no stage node to wait for
            graph.add(replay_specs)
        while True:
            exited = graph.first_exited()
            if exited is not None:
                label, code = exited
                if label == 'replay' and code == 0:
                    print('[launch] replay finished; stopping the graph', flush=True)
                    graph.stop()
                    return 0
                print(f'[launch] ERROR: {label} exited with code {code}; stopping the graph',
                      file=sys.stderr, flush=True)
                graph.stop()
                return 1
            if monitor is None:
                time.sleep(0.2)
                continue
            monitor.poll(0.2)
            for name in sorted(set(monitor.errors) - reported):   # each once, not at 1 Hz
                print(f'[launch] ERROR: {name}: {monitor.errors[name]}', file=sys.stderr,
                      flush=True)
                reported.add(name)
            if monitor.all_ready:
                print(f'[launch] {monitor.summary()}', flush=True)
                monitor.close()
                monitor = None
                graph.add(replay_specs)   # the bag starts once every stage can take frames
    except KeyboardInterrupt:
        graph.stop()
        for label, child in graph.children.items():   # a node that did not stop in order
            if child.returncode:
                print(f'[launch] {label} exited with code {child.returncode} when stopped',
                      file=sys.stderr, flush=True)
        return 0
    finally:
        if monitor is not None:
            monitor.close()
        if stages:   # _readiness_monitor started rclpy
            import rclpy

            rclpy.try_shutdown()


def _readiness_monitor(stages: list[str]):
    """A :class:`ReadinessMonitor` of ``stages`` (rclpy initialised here), or None."""
    if not stages:
        return None
    from tlessbot_ros.nodes.common import init_ros
    from tlessbot_ros.tools.support.readiness import ReadinessMonitor

    init_ros()
    return ReadinessMonitor(stages, node_name='tlessbot_launch')
