"""When ``tlessbot launch`` starts a dead process again: back-off, limits, what to report.

Pure bookkeeping (no processes, no ROS, the caller's clock): :class:`Respawner` is told that
a process exited and when it was started again; it says when to restart it, or that launch must
give up, and gives the key-values launch publishes on /diagnostics.
"""
from __future__ import annotations

import signal
import time
from collections import deque
from dataclasses import dataclass, field

LAUNCH_STATUS = 'tlessbot_launch'   # the name of launch's own status on /diagnostics


@dataclass(frozen=True)
class RespawnPolicy:
    """How launch restarts a process that died.

    Attributes:
        enabled: restart at all (False: a death stops the graph).
        delay_s: back-off before the first restart, doubled for each further death in a row.
        max_delay_s: the back-off never exceeds this.
        healthy_s: a process that ran this long before it died starts the back-off again at
            ``delay_s`` (its death is not part of a crash loop).
        max_restarts: restarts of one process within ``window_s`` after which launch gives up
            and stops the graph (a crash loop the back-off alone would repeat forever).
        window_s: see ``max_restarts``.
    """

    enabled: bool = True
    delay_s: float = 1.0
    max_delay_s: float = 30.0
    healthy_s: float = 60.0
    max_restarts: int = 5
    window_s: float = 600.0

    def __post_init__(self) -> None:
        if not 0 < self.delay_s <= self.max_delay_s:
            raise ValueError(f'the respawn delay must be > 0 and <= the maximum delay, got '
                             f'{self.delay_s:g} s and {self.max_delay_s:g} s')
        if self.max_restarts < 1 or self.window_s <= 0 or self.healthy_s < 0:
            raise ValueError('max restarts must be >= 1, the window > 0 s and healthy >= 0 s')


@dataclass
class ProcessRestarts:
    """One process's restarts (what /diagnostics shows, and the back-off state)."""

    restarts: int = 0
    last_exit: int | None = None
    last_restart_wall: float | None = None   # seconds since the epoch
    deaths_in_row: int = 0
    restart_at: float | None = None          # monotonic; set while a restart is pending
    recent: deque[float] = field(default_factory=deque)   # monotonic restart times


@dataclass(frozen=True)
class ExitDecision:
    """What to do about a process that exited: restart it after ``delay_s``, or give up
    (``delay_s`` None) for ``reason``."""

    delay_s: float | None
    reason: str = ''


def describe_exit(code: int) -> str:
    """``'code 1'`` or ``'code -9 (SIGKILL)'`` for a Popen return code."""
    if code < 0:
        try:
            return f'code {code} ({signal.Signals(-code).name})'
        except ValueError:
            pass
    return f'code {code}'


class Respawner:
    """Back-off and restart limits per process label.

    Example:
        >>> respawner = Respawner(RespawnPolicy(), ['localiser'])
        >>> respawner.on_exit('localiser', -9, now=100.0, uptime_s=30.0).delay_s
        1.0
        >>> respawner.due(101.0)
        ['localiser']
        >>> respawner.restarted('localiser', now=101.0)
    """

    def __init__(self, policy: RespawnPolicy, labels: list[str]) -> None:
        self.policy = policy
        self.records = {label: ProcessRestarts() for label in labels}

    def on_exit(self, label: str, code: int, *, now: float, uptime_s: float,
                ever_ready: bool | None = None) -> ExitDecision:
        """``label`` exited with Popen return ``code`` after ``uptime_s``; ``ever_ready``:
        whether it reported ready since its start (None: it has no readiness to report)."""
        record = self.records[label]
        record.last_exit = code
        policy = self.policy
        if not policy.enabled:
            return ExitDecision(None, 'respawn is off')
        if code == 0:
            return ExitDecision(None, 'it ended by itself (exit code 0), not by a crash')
        if code > 0 and ever_ready is False:
            # A bad parameter or a missing model file: starting again would fail again.
            return ExitDecision(None, 'it failed before it was ready (a start-up error: see '
                                      'its output above)')
        while record.recent and now - record.recent[0] > policy.window_s:
            record.recent.popleft()
        if len(record.recent) >= policy.max_restarts:
            return ExitDecision(None, f'it was restarted {len(record.recent)} times within '
                                      f'{policy.window_s:g} s')
        record.deaths_in_row = 1 if uptime_s >= policy.healthy_s else record.deaths_in_row + 1
        delay = min(policy.max_delay_s, policy.delay_s * 2 ** (record.deaths_in_row - 1))
        record.restart_at = now + delay
        return ExitDecision(delay)

    def due(self, now: float) -> list[str]:
        """Labels whose restart is due at ``now``."""
        return [label for label, record in self.records.items()
                if record.restart_at is not None and record.restart_at <= now]

    def waiting(self, label: str) -> bool:
        """``label`` is dead and waiting for its restart."""
        return self.records[label].restart_at is not None

    def restarted(self, label: str, *, now: float, wall: float | None = None) -> None:
        record = self.records[label]
        record.restart_at = None
        record.restarts += 1
        record.recent.append(now)
        record.last_restart_wall = time.time() if wall is None else wall

    def diagnostic_values(self) -> dict[str, str]:
        """``{label.restarts, label.last_exit, label.last_restart}`` of every process that has
        exited at least once (last_restart: local time, ISO 8601)."""
        values = {}
        for label, record in self.records.items():
            if record.last_exit is None:
                continue
            values[f'{label}.restarts'] = str(record.restarts)
            values[f'{label}.last_exit'] = str(record.last_exit)
            if record.last_restart_wall is not None:
                values[f'{label}.last_restart'] = time.strftime(
                    '%Y-%m-%dT%H:%M:%S', time.localtime(record.last_restart_wall))
        return values
