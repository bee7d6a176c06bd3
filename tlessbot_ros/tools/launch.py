"""Start the perception graph, every node in its own OS process (like `ros2 launch`).

    tlessbot launch                              # two camera drivers + the perception nodes
    tlessbot launch --replay bags/demo.mcap      # the bag stands in for the cameras
    tlessbot launch --nodes localiser classifier # a subset

Each node gets ``--ros-args --params-file <config>``; output lines are prefixed with the node's
name. Ctrl-C or SIGTERM is passed on to every node (as SIGINT). If a node dies, the others are
stopped and launch exits non-zero, naming the node and its exit code.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.config import default_config_path

CAMERAS = ('top', 'side')
PERCEPTION_NODES = ('localiser', 'classifier', 'pose_estimator')


@dataclass(frozen=True)
class ProcessSpec:
    """One process of the graph: a label and its argv."""

    label: str
    argv: list[str] = field(default_factory=list)


def node_available(executable: str) -> bool:
    return importlib.util.find_spec(f'tlessbot_ros.nodes.{executable}') is not None


def graph_processes(config: Path, *, replay: str | None = None, rate: float = 1.0,
                    loop: bool = False, nodes: list[str] | None = None,
                    extra_ros_args: list[str] | None = None) -> list[ProcessSpec]:
    """The processes of the graph (pure: nothing is started)."""
    python = sys.executable
    specs = []
    wanted = nodes or ['camera_driver', *PERCEPTION_NODES]
    for name in wanted:
        if not node_available(name):
            raise TlessbotError(f'node {name!r} is not part of this installation')
    ros_args = ['--ros-args', '--params-file', str(config), *(extra_ros_args or [])]
    if replay is not None:
        argv = [python, '-m', 'tlessbot_ros.tools.cli', 'replay', replay, '--rate', str(rate),
                '--wait-for-subscribers', '10']
        specs.append(ProcessSpec('replay', argv + (['--loop'] if loop else [])))
    for name in wanted:
        if name == 'camera_driver':
            if replay is not None:
                continue
            for camera in CAMERAS:
                specs.append(ProcessSpec(f'camera_driver/{camera}', [
                    python, '-m', 'tlessbot_ros.nodes.camera_driver', *ros_args,
                    '-r', f'__ns:=/{camera}', '-p', f'camera_name:={camera}']))
        else:
            specs.append(ProcessSpec(name, [python, '-m', f'tlessbot_ros.nodes.{name}',
                                            *ros_args]))
    return specs


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


class GraphProcesses:
    """Runs ProcessSpecs as children, prefixes their output, stops them all together."""

    def __init__(self, specs: list[ProcessSpec], *, env: dict[str, str] | None = None) -> None:
        self.specs = specs
        self.env = env
        self.children: dict[str, subprocess.Popen] = {}
        self._threads: list[threading.Thread] = []

    def start(self) -> None:
        """Start every process; their output is echoed with a ``[label]`` prefix."""
        self._start(sink=None)

    def start_capturing(self, sink: list[str]) -> None:
        """Start every process; their prefixed output lines are appended to ``sink``."""
        self._start(sink=sink)

    def _start(self, sink: list[str] | None) -> None:
        for spec in self.specs:
            child = subprocess.Popen(spec.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                     text=True, bufsize=1, env=self.env)
            self.children[spec.label] = child
            thread = threading.Thread(target=self._pump, args=(spec.label, child, sink),
                                      daemon=True)
            thread.start()
            self._threads.append(thread)

    @staticmethod
    def _pump(label: str, child: subprocess.Popen, sink: list[str] | None) -> None:
        assert child.stdout is not None
        for line in child.stdout:
            if sink is not None:
                sink.append(f'[{label}] {line}')
            else:
                sys.stdout.write(f'[{label}] {line}')
                sys.stdout.flush()

    def first_exited(self) -> tuple[str, int] | None:
        for label, child in self.children.items():
            code = child.poll()
            if code is not None:
                return label, code
        return None

    def stop(self, timeout_s: float = 10.0) -> None:
        """SIGINT every child (as Ctrl-C would), then SIGTERM / SIGKILL stragglers."""
        for child in self.children.values():
            if child.poll() is None:
                child.send_signal(signal.SIGINT)
        deadline = time.monotonic() + timeout_s
        for child in self.children.values():
            remaining = max(0.1, deadline - time.monotonic())
            try:
                child.wait(timeout=remaining)
            except subprocess.TimeoutExpired:
                child.terminate()
                try:
                    child.wait(timeout=3)
                except subprocess.TimeoutExpired:
                    child.kill()
        for thread in self._threads:
            thread.join(timeout=2)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt


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
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _interrupt)
    graph = GraphProcesses(specs, env=dict(os.environ))
    graph.start()
    print(f'launched {len(specs)} processes: ' + ', '.join(s.label for s in specs), flush=True)
    try:
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
            time.sleep(0.2)
    except KeyboardInterrupt:
        graph.stop()
        return 0
