"""What a process tree uses, read from Linux /proc: RSS, CPU time, open file descriptors and
threads of a process and its descendants (a node's worker processes count as the node's)."""
from __future__ import annotations

from pathlib import Path

from tlessbot_ros.parallel.spare_cpu import read_process_cpu_s


def children_by_parent() -> dict[int, list[int]]:
    """{parent pid: child pids} of every process (one scan of Linux /proc)."""
    parents: dict[int, list[int]] = {}
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            ppid = int(stat.read_text().rsplit(')', 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        parents.setdefault(ppid, []).append(int(stat.parent.name))
    return parents


def process_tree(pid: int, parents: dict[int, list[int]] | None = None) -> list[int]:
    """``pid`` and all its descendants (a node's worker processes count as the node's);
    ``parents`` from :func:`children_by_parent`, scanned here when not given."""
    parents = children_by_parent() if parents is None else parents
    tree, frontier = [pid], [pid]
    while frontier:
        frontier = [child for parent in frontier for child in parents.get(parent, [])]
        tree += frontier
    return tree


def cpu_seconds(pid: int, *, descendants: bool = True) -> float:
    """User + system CPU time used by a process (and its descendants), seconds (Linux /proc)."""
    total = 0.0
    for member in process_tree(pid) if descendants else [pid]:
        seconds = read_process_cpu_s(member)
        if seconds is None and member == pid:
            return float('nan')
        total += seconds or 0.0
    return total


def open_fds(pid: int, parents: dict[int, list[int]] | None = None) -> int:
    """Open file descriptors of a process and its descendants (Linux /proc; -1: none read)."""
    total, found = 0, False
    for member in process_tree(pid, parents):
        try:
            total += sum(1 for _ in Path(f'/proc/{member}/fd').iterdir())
            found = True
        except OSError:
            pass
    return total if found else -1


def thread_count(pid: int, parents: dict[int, list[int]] | None = None) -> int:
    """Threads of a process and its descendants (Linux /proc; -1: none read)."""
    total, found = 0, False
    for member in process_tree(pid, parents):
        try:
            for line in Path(f'/proc/{member}/status').read_text().splitlines():
                if line.startswith('Threads:'):
                    total += int(line.split()[1])
                    found = True
        except (OSError, ValueError):
            pass
    return total if found else -1


def rss_mb(pid: int, parents: dict[int, list[int]] | None = None) -> float:
    """Resident set size of a process and its descendants in MiB (Linux /proc; ``parents``
    as for :func:`process_tree`)."""
    total, found = 0.0, False
    for member in process_tree(pid, parents):
        try:
            for line in Path(f'/proc/{member}/status').read_text().splitlines():
                if line.startswith('VmRSS:'):
                    total += int(line.split()[1]) / 1024.0
                    found = True
        except OSError:
            pass
    return total if found else float('nan')


__all__ = ['children_by_parent', 'cpu_seconds', 'open_fds', 'process_tree', 'rss_mb',
           'thread_count']
