"""Start the perception graph, every node in its own OS process (like `ros2 launch`).

    tlessbot launch                              # two camera drivers + the perception nodes
    tlessbot launch --replay bags/demo.mcap      # the bag stands in for the cameras
    tlessbot launch --nodes localiser classifier # a subset

Each node gets ``--ros-args --params-file <config>``; output lines are prefixed with the node's
name. Once every stage node reports ready on /diagnostics, launch prints one line
(``[launch] graph ready in 6.2 s (localiser 1.9 s, ...)``); with ``--replay`` the bag starts
only then, so no frame is sent to a node that cannot take it yet. Ctrl-C or SIGTERM is passed
on to every node (as SIGINT).

A node or camera driver that dies (a crash, ``kill -9``, the OOM killer) is started again
after a back-off (``--respawn-delay``, doubled for each death in a row up to
``--respawn-max-delay``); launch prints when it is ready again and reports every process's
restarts on /diagnostics (status ``tlessbot_launch``). Launch gives up and stops the graph,
naming the node and its exit code, when a node was restarted ``--max-restarts`` times within
10 minutes, when a stage node fails before it was ever ready (a start-up error, e.g. a bad
parameter), when a node ends by itself with code 0, and with ``--no-respawn`` at any death.
The replay is not restarted: it would send the bag from its start again.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from tlessbot_ros.core.common.rig import CAMERA_NAMES
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path, load_ros_params
from tlessbot_ros.tools.support.cell_graph import DISCOVERY_VARIABLE, discovery_range
from tlessbot_ros.tools.support.processes import (
    PERCEPTION_NODES,
    GraphProcesses,
    graph_processes,
)
from tlessbot_ros.tools.support.respawn import (
    LAUNCH_STATUS,
    Respawner,
    RespawnPolicy,
    describe_exit,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument('--config', default=None,
                        help='parameter YAML (default: config/cell.yaml)')
    parser.add_argument('--parts', default=None, metavar='DIR',
                        help="parts folder (tlessbot parts build; default: the config's "
                             'parts_path, else the packaged T-LESS parts)')
    parser.add_argument('--replay', default=None, metavar='BAG',
                        help='replay this bag instead of starting the camera drivers')
    parser.add_argument('--rate', type=float, default=1.0, help='replay rate')
    parser.add_argument('--loop', action='store_true',
                        help='replay in a loop, each frame stamped when it is sent')
    parser.add_argument('-p', '--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='parameter override for every node (repeatable), e.g. '
                             '-p templates_path:=my_templates.npz')
    for camera in CAMERA_NAMES:
        parser.add_argument(f'--{camera}-serial', default='', metavar='SERIAL',
                            help=f'serial number of the {camera} camera (default: any device)')
    parser.add_argument('--output-frame', choices=('camera', 'world'), default=None,
                        help="frame of the published poses (default: the parameter file's)")
    parser.add_argument('--foxglove', action='store_true',
                        help='also start the Foxglove live view (ws://127.0.0.1:8765)')
    parser.add_argument('--discovery-range', default=None, metavar='RANGE',
                        help='ROS_AUTOMATIC_DISCOVERY_RANGE of the graph: LOCALHOST (private, '
                             "default), SUBNET (two PCs); default: the config's discovery_range")
    parser.add_argument('--nodes', nargs='+', default=None,
                        help='only these nodes (camera_driver, localiser, classifier, '
                             'pose_estimator, objects, foxglove_view)')
    defaults = RespawnPolicy()
    parser.add_argument('--respawn', action=argparse.BooleanOptionalAction, default=True,
                        help='start a node that died again (default); --no-respawn: stop the '
                             'graph instead')
    parser.add_argument('--respawn-delay', type=float, default=defaults.delay_s, metavar='S',
                        help='seconds before the first restart of a node, doubled for each '
                             f'death in a row (default {defaults.delay_s:g})')
    parser.add_argument('--respawn-max-delay', type=float, default=defaults.max_delay_s,
                        metavar='S', help=f'longest back-off (default {defaults.max_delay_s:g})')
    parser.add_argument('--max-restarts', type=int, default=defaults.max_restarts, metavar='N',
                        help='give up and stop the graph when a node was restarted N times '
                             f'within {defaults.window_s / 60:g} minutes '
                             f'(default {defaults.max_restarts})')


def _policy(args: argparse.Namespace) -> RespawnPolicy:
    try:
        return RespawnPolicy(enabled=args.respawn, delay_s=args.respawn_delay,
                             max_delay_s=args.respawn_max_delay, max_restarts=args.max_restarts)
    except ValueError as error:
        raise TlessbotError(str(error)) from None


def _one_camera_params(replay: str | None, config: Path) -> list[str]:
    """``rig.cameras:=[NAME]`` when the replayed bag has one camera under the graph's names
    (:func:`~tlessbot_ros.tools.support.bag_inputs.replay_cameras`), else nothing."""
    if not replay:
        return []
    from tlessbot_ros.tools.support.bag_inputs import replay_cameras
    from tlessbot_ros.tools.support.rig import load_rig

    cameras = replay_cameras(replay, list(load_rig(config).cameras))
    if not cameras:
        return []
    print(f'[launch] {replay} has the {cameras[0]} camera alone: rig.cameras [{cameras[0]}]',
          flush=True)
    return [f'rig.cameras:=[{", ".join(cameras)}]']


def run(args: argparse.Namespace) -> int:
    config = Path(args.config) if args.config else default_config_path()
    if not config.is_file():
        raise TlessbotError(f'parameter file not found: {config}')
    for override in args.param:
        if ':=' not in override:
            raise TlessbotError(f'parameter override must look like NAME:=VALUE, got {override!r}')
    if args.parts:   # refused here, in one line, before any process starts
        from tlessbot_ros.io.parts import open_parts_folder
        from tlessbot_ros.tools.support.rig import load_rig

        open_parts_folder(args.parts, rig=load_rig(config))
    policy = _policy(args)
    os.environ[DISCOVERY_VARIABLE] = discovery_range(
        argument=args.discovery_range,
        config_value=load_ros_params(config).get('discovery_range'), environ=dict(os.environ))
    params = [*args.param, *_one_camera_params(args.replay, config)]
    specs = graph_processes(config, replay=args.replay, rate=args.rate, loop=args.loop,
                            parts=args.parts,
                            nodes=args.nodes, output_frame=args.output_frame,
                            foxglove=args.foxglove,
                            serials={c: getattr(args, f'{c}_serial') for c in CAMERA_NAMES},
                            extra_ros_args=[a for o in params for a in ('-p', o)])
    # Stop the graph on Ctrl-C and on SIGTERM (systemd, docker stop, kill), never leaving the
    # nodes orphaned; SIGINT is handled even when a shell started launch in the background,
    # which makes it ignore SIGINT.
    from tlessbot_ros.nodes.common import interrupt_on_signals, raise_if_interrupted

    interrupt_on_signals()
    replay_specs = [s for s in specs if s.label == 'replay']
    graph = GraphProcesses([s for s in specs if s.label != 'replay'], env=dict(os.environ))
    stages = [s.label for s in graph.specs if s.label in PERCEPTION_NODES]
    monitor = None
    try:
        graph.start()
        print(f'launched {len(graph.specs)} processes: '
              + ', '.join(s.label for s in graph.specs), flush=True)
        monitor = _readiness_monitor(stages)
        supervisor = _Supervisor(graph, monitor, stages, Respawner(
            policy, [s.label for s in graph.specs]))
        if monitor is None:   # no stage node to wait for
            graph.add(replay_specs)
        while True:
            raise_if_interrupted()
            code = supervisor.step()
            if code is not None:
                graph.stop()
                return code
            if monitor is not None and supervisor.replay_due():
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


class _Supervisor:
    """One pass at a time over the graph: deaths, due restarts, readiness, launch's status."""

    def __init__(self, graph: GraphProcesses, monitor, stages: list[str],
                 respawner: Respawner) -> None:
        self.graph, self.monitor, self.stages, self.respawner = graph, monitor, stages, respawner
        self.graph_ready = monitor is None
        self.reported: set[str] = set()   # nodes whose failed warm-up was printed
        self.recovering: dict[str, tuple[int, float]] = {}   # label: (exit code, when)
        self.next_status = 0.0
        self.status_publisher = None if monitor is None else _status_publisher(monitor.node)
        if monitor is not None:
            for label in stages:
                monitor.restarted(label, graph.children[label].pid)

    def step(self) -> int | None:
        """Handle what happened since the last step; the exit code once launch must end."""
        now = time.monotonic()
        for label, code in self.graph.exited():
            if label == 'replay':
                return self._replay_ended(code)
            if self.respawner.waiting(label):
                continue
            decision = self.respawner.on_exit(
                label, code, now=now, uptime_s=now - self.graph.started[label],
                ever_ready=self.monitor.is_ready(label) if label in self.stages else None)
            if decision.delay_s is None:
                print(f'[launch] ERROR: {label} exited with {describe_exit(code)}; not '
                      f'restarted: {decision.reason}; stopping the graph', file=sys.stderr,
                      flush=True)
                self._publish_status(force=True, failed=label)
                return 1
            print(f'[launch] {label} exited with {describe_exit(code)}; restarting it in '
                  f'{decision.delay_s:.1f} s', flush=True)
            self.recovering[label] = (code, now)
        for label in self.respawner.due(now):
            child = self.graph.restart(label)
            self.respawner.restarted(label, now=now)
            if label in self.stages:
                self.monitor.restarted(label, child.pid)
            else:   # no readiness to wait for
                code, _ = self.recovering.pop(label)
                print(f'[launch] {label} restarted (exit {code})', flush=True)
        if self.monitor is None:
            time.sleep(0.2)
            return None
        self.monitor.poll(0.2)
        self._report_readiness()
        self._publish_status()
        return None

    def replay_due(self) -> bool:
        """True once, when every stage node is first ready."""
        if self.graph_ready or not self.monitor.all_ready:
            return False
        self.graph_ready = True
        print(f'[launch] {self.monitor.summary()}', flush=True)
        return True

    def _replay_ended(self, code: int) -> int:
        if code == 0:
            print('[launch] replay finished; stopping the graph', flush=True)
            return 0
        # Not restarted: a new replay would send the bag from its start again, and a replay
        # fails on its input (a bad bag), which a restart does not mend.
        print(f'[launch] ERROR: replay exited with {describe_exit(code)}; stopping the graph',
              file=sys.stderr, flush=True)
        return 1

    def _report_readiness(self) -> None:
        monitor = self.monitor
        for name in sorted(set(monitor.errors) - self.reported):   # each once, not at 1 Hz
            print(f'[launch] ERROR: {name}: {monitor.errors[name]}', file=sys.stderr,
                  flush=True)
            self.reported.add(name)
        for label, (code, exited_at) in list(self.recovering.items()):
            if label in self.stages and not self.respawner.waiting(label) and \
                    monitor.is_ready(label):
                print(f'[launch] {label} restarted (exit {code}), ready again in '
                      f'{time.monotonic() - exited_at:.1f} s', flush=True)
                del self.recovering[label]
                self.reported.discard(label)

    def _publish_status(self, *, force: bool = False, failed: str = '') -> None:
        """Launch's status on /diagnostics, at 1 Hz: every process's restarts, which are
        down or starting again, and (ERROR) the one launch gave up on."""
        from tlessbot_ros.nodes.diagnostics import ERROR, OK, WARN, diagnostic_array

        if self.status_publisher is None or (not force and time.monotonic() < self.next_status):
            return
        self.next_status = time.monotonic() + 1.0
        down = sorted(self.recovering)
        if failed:
            level, message = ERROR, f'{failed} failed; stopping the graph'
        elif down:
            level, message = WARN, 'restarting ' + ', '.join(down)
        else:
            level, message = OK, 'all processes running'
        values = {'processes': len(self.graph.children),
                  'restarts': sum(r.restarts for r in self.respawner.records.values()),
                  **self.respawner.diagnostic_values()}
        self.status_publisher.publish(diagnostic_array(
            self.monitor.node.get_clock().now().to_msg(), LAUNCH_STATUS, level, message,
            values))


def _status_publisher(node):
    """A /diagnostics publisher on ``node`` (rclpy is imported only when launch runs stages)."""
    from tlessbot_ros.conversions.topics import DIAGNOSTICS
    from tlessbot_ros.nodes.common import RESULT_QOS, message_class

    return node.create_publisher(message_class('diagnostic_msgs/msg/DiagnosticArray'),
                                 DIAGNOSTICS, RESULT_QOS)


def _readiness_monitor(stages: list[str]):
    """A :class:`ReadinessMonitor` of ``stages`` (rclpy initialised here), or None."""
    if not stages:
        return None
    from tlessbot_ros.nodes.common import init_ros
    from tlessbot_ros.tools.support.readiness import ReadinessMonitor

    init_ros()
    return ReadinessMonitor(stages, node_name=LAUNCH_STATUS)
