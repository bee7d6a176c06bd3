"""The perception graph's processes: what to start (pure) and running them together."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from tlessbot_ros.tools.support.cell_graph import (
    PERCEPTION_NODES,
    GraphProcess,
    graph_description,
)

__all__ = ['PERCEPTION_NODES', 'GraphProcesses', 'ProcessSpec', 'graph_processes',
           'same_code_env']


@dataclass(frozen=True)
class ProcessSpec:
    """One process of the graph: a label and its argv."""

    label: str
    argv: list[str] = field(default_factory=list)


def graph_processes(config: Path, *, replay: str | None = None, rate: float = 1.0,
                    loop: bool = False, nodes: list[str] | None = None,
                    extra_ros_args: list[str] | None = None,
                    serials: dict[str, str] | None = None,
                    output_frame: str | None = None,
                    parts: str | None = None,
                    foxglove: bool = False) -> list[ProcessSpec]:
    """The processes of :func:`cell_graph.graph_description` as argvs of this Python (pure:
    nothing is started). Each node gets ``--ros-args --params-file config``, then
    ``extra_ros_args``, then the description's namespace and parameter overrides."""
    description = graph_description(replay=replay, rate=rate, loop=loop, nodes=nodes,
                                     serials=serials, output_frame=output_frame, parts=parts,
                                     foxglove=foxglove)
    return [ProcessSpec(process.label, _argv(process, config, extra_ros_args or []))
            for process in description]


def _argv(process: GraphProcess, config: Path, extra_ros_args: list[str]) -> list[str]:
    if not process.is_node:
        return [sys.executable, '-m', 'tlessbot_ros.tools.cli', *process.arguments]
    argv = [sys.executable, '-m', f'tlessbot_ros.nodes.{process.executable}', *process.arguments,
            '--ros-args', '--params-file', str(config), *extra_ros_args]
    if process.namespace:
        argv += ['-r', f'__ns:={process.namespace}']
    for name, value in process.overrides:
        argv += ['-p', f'{name}:={value}']
    return argv


def same_code_env(env: dict[str, str] | None = None) -> dict[str, str]:
    """``env`` (default: this process's) for children that must run the same tlessbot_ros as
    this process: the directory holding it goes first on ``PYTHONPATH``, and
    ``PYTHONSAFEPATH`` keeps ``python -m`` from putting the working directory before it
    (Python 3.11+). Otherwise a child started in a source checkout imports that checkout's
    package, whatever this process runs: a benchmark of another tree (``git archive`` on
    ``PYTHONPATH``) started from the repository measured the repository's nodes."""
    env = dict(os.environ if env is None else env)
    root = Path(__file__).resolve().parents[3]
    # an installed package is found by the children as by this process; a site directory
    # first on PYTHONPATH would come before the standard library
    if root.name not in ('site-packages', 'dist-packages'):
        paths = [p for p in env.get('PYTHONPATH', '').split(os.pathsep) if p and p != str(root)]
        env['PYTHONPATH'] = os.pathsep.join([str(root), *paths])
    env['PYTHONSAFEPATH'] = '1'
    return env


class GraphProcesses:
    """Runs ProcessSpecs as children, prefixes their output, restarts one that exited
    (:meth:`restart`), stops them all together."""

    def __init__(self, specs: list[ProcessSpec], *, env: dict[str, str] | None = None) -> None:
        self.specs = specs
        self.env = same_code_env(env)   # the children run this process's tlessbot_ros
        self.children: dict[str, subprocess.Popen] = {}
        self.started: dict[str, float] = {}   # monotonic time of each child's (re)start
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
            self._spawn(spec)

    def _spawn(self, spec: ProcessSpec) -> subprocess.Popen:
        child = subprocess.Popen(spec.argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                                 text=True, bufsize=1, env=self.env)
        self.children[spec.label] = child
        self.started[spec.label] = time.monotonic()
        thread = threading.Thread(target=self._pump, args=(spec.label, child, self._sink),
                                  daemon=True)
        thread.start()
        self._threads.append(thread)
        return child

    def restart(self, label: str) -> subprocess.Popen:
        """Start ``label``'s process again after it exited (same argv, output as before).

        Raises:
            RuntimeError: it is still running.
        """
        if self.children[label].poll() is None:
            raise RuntimeError(f'{label} is still running')
        self._threads = [t for t in self._threads if t.is_alive()]
        return self._spawn(next(s for s in self.specs if s.label == label))

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
        exited = self.exited()
        return exited[0] if exited else None

    def exited(self) -> list[tuple[str, int]]:
        """(label, return code) of every child that has exited (negative: killed by that
        signal), in start order."""
        return [(label, code) for label, child in self.children.items()
                if (code := child.poll()) is not None]

    def stop(self, timeout_s: float = 30.0) -> None:
        """SIGINT every child (as Ctrl-C would), then SIGTERM / SIGKILL stragglers.

        A node stopped by SIGINT finishes the frame in hand and stops its worker processes
        first, which on a heavily loaded host can take many seconds
        (docs/bench/time-and-shutdown.md), hence the generous wait.
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
