"""Waiting for the stage nodes to say they are ready (their ``ready`` key on /diagnostics)."""
from __future__ import annotations

import time
from collections.abc import Callable, Iterable


class ReadinessMonitor:
    """Listens to /diagnostics for the named stage nodes' readiness.

    Each stage node reports WARN 'starting' with ``ready: false`` while it warms up, then OK
    with ``ready: true`` and ``ready_after_s`` (seconds from its start), and its ``pid``.
    Create after ``rclpy.init``; call :meth:`poll` from the thread that owns it.

    A node restarted in a new process is :meth:`restarted`: it is not ready again until that
    process says so (a status of the dead one still on its way is not taken for it).
    """

    def __init__(self, names: Iterable[str], *, node_name: str = 'tlessbot_readiness') -> None:
        import rclpy

        from tlessbot_ros.conversions.messages import message_class
        from tlessbot_ros.conversions.topics import DIAGNOSTICS
        from tlessbot_ros.nodes.common import RESULT_QOS

        self.expected = tuple(names)
        self.ready_after_s: dict[str, float] = {}
        self.errors: dict[str, str] = {}
        self._pids: dict[str, str] = {}   # the process each name's status must come from
        self.started = time.monotonic()
        self._node = rclpy.create_node(node_name)
        self._node.create_subscription(message_class('diagnostic_msgs/msg/DiagnosticArray'),
                                       DIAGNOSTICS, self._on_diagnostics, RESULT_QOS)

    def _on_diagnostics(self, msg) -> None:
        for status in msg.status:
            if status.name not in self.expected:
                continue
            values = {kv.key: kv.value for kv in status.values}
            expected_pid = self._pids.get(status.name)
            if expected_pid is not None and values.get('pid', expected_pid) != expected_pid:
                continue
            if values.get('ready') == 'true':
                self.ready_after_s.setdefault(status.name, float(values.get('ready_after_s',
                                                                            'nan')))
            elif status.message.startswith('warm-up failed'):
                self.errors[status.name] = status.message

    def restarted(self, name: str, pid: int) -> None:
        """``name`` runs again as process ``pid``: not ready until that process reports it."""
        self._pids[name] = str(pid)
        self.ready_after_s.pop(name, None)
        self.errors.pop(name, None)

    def is_ready(self, name: str) -> bool:
        return name in self.ready_after_s

    @property
    def node(self):
        """The monitor's rclpy node (launch publishes its own status through it)."""
        return self._node

    @property
    def all_ready(self) -> bool:
        return all(name in self.ready_after_s for name in self.expected)

    def poll(self, timeout_s: float = 0.1) -> None:
        """Handle what has arrived, waiting up to ``timeout_s``."""
        import rclpy

        rclpy.spin_once(self._node, timeout_sec=timeout_s)

    def summary(self) -> str:
        """One line: how long the whole graph took to get ready, and each node."""
        nodes = ', '.join(f'{name} {self.ready_after_s[name]:.1f} s' for name in self.expected
                          if name in self.ready_after_s)
        return f'graph ready in {time.monotonic() - self.started:.1f} s ({nodes})'

    def close(self) -> None:
        self._node.destroy_node()


def wait_until_ready(names: Iterable[str], *, report: Callable[[str], None],
                     node_name: str = 'tlessbot_wait_ready') -> ReadinessMonitor:
    """Block until every node of ``names`` reports ready (after ``rclpy.init``); a failed
    warm-up is reported once per node and the wait goes on (a respawned node may recover).
    Returns the closed monitor, whose :meth:`~ReadinessMonitor.summary` says how long it took.
    """
    monitor = ReadinessMonitor(names, node_name=node_name)
    reported: set[str] = set()
    try:
        while not monitor.all_ready:
            monitor.poll(0.2)
            for name in sorted(set(monitor.errors) - reported):
                report(f'{name}: {monitor.errors[name]}')
                reported.add(name)
    finally:
        monitor.close()
    return monitor
