"""The perception graph's processes: what to start (pure) and running them together."""
from __future__ import annotations

import importlib.util
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from tlessbot_ros.core.common import CAMERA_NAMES
from tlessbot_ros.errors import TlessbotError

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
            for camera in CAMERA_NAMES:
                specs.append(ProcessSpec(f'camera_driver/{camera}', [
                    python, '-m', 'tlessbot_ros.nodes.camera_driver', *ros_args,
                    '-r', f'__ns:=/{camera}', '-p', f'camera_name:={camera}']))
        else:
            specs.append(ProcessSpec(name, [python, '-m', f'tlessbot_ros.nodes.{name}',
                                            *ros_args]))
    return specs


class GraphProcesses:
    """Runs ProcessSpecs as children, prefixes their output, stops them all together."""

    def __init__(self, specs: list[ProcessSpec], *, env: dict[str, str] | None = None) -> None:
        self.specs = specs
        self.env = env
        self.children: dict[str, subprocess.Popen] = {}
        self._threads: list[threading.Thread] = []
        self._sink: list[str] | None = None

    def start(self) -> None:
        """Start every process; their output is echoed with a ``[label]`` prefix."""
        self._start(sink=None)

    def start_capturing(self, sink: list[str]) -> None:
        """Start every process; their prefixed output lines are appended to ``sink``."""
        self._start(sink=sink)

    def add(self, specs: list[ProcessSpec]) -> None:
        """Start more processes into the running graph (output as :meth:`start`'s)."""
        self.specs = [*self.specs, *specs]
        self._start(sink=self._sink, specs=specs)

    def _start(self, sink: list[str] | None, specs: list[ProcessSpec] | None = None) -> None:
        self._sink = sink
        for spec in self.specs if specs is None else specs:
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

    def stop(self, timeout_s: float = 30.0) -> None:
        """SIGINT every child (as Ctrl-C would), then SIGTERM / SIGKILL stragglers.

        A node stopped by SIGINT finishes the frame in hand and stops its worker processes
        first; with the 2-core machine at a load average of 17 the pose estimator once took
        more than 10 s, hence the generous wait.
        """
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
