"""pytest plugin of :mod:`run_suite`: a journal of the tests that started, ended and failed.

Loaded by ``run_suite.py`` (``-p suite_journal``) with ``TLESSBOT_TEST_JOURNAL`` naming the file.
A run that goes on after a hung test deselects the tests the journal says ended.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

JOURNAL_VARIABLE = 'TLESSBOT_TEST_JOURNAL'


def _path() -> Path | None:
    value = os.environ.get(JOURNAL_VARIABLE)
    return Path(value) if value else None


def write_event(event: str, nodeid: str) -> None:
    path = _path()
    if path is not None:
        with path.open('a') as out:   # written through at once: the process may be ended
            out.write(json.dumps([event, nodeid]) + '\n')


def read_events(path: Path) -> list[tuple[str, str]]:
    """The journal's (event, test id) pairs; a line cut short when the process ended is left."""
    events = []
    if path.exists():
        for line in path.read_text().splitlines():
            try:
                event, nodeid = json.loads(line)
            except ValueError:
                continue
            events.append((event, nodeid))
    return events


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    path = _path()
    ended = {n for e, n in read_events(path) if e == 'end'} if path is not None else set()
    if ended:   # a run going on after a hang: the tests that ran already are not run again
        config.hook.pytest_deselected(items=[i for i in items if i.nodeid in ended])
        items[:] = [i for i in items if i.nodeid not in ended]


def pytest_runtest_logstart(nodeid: str, location: tuple) -> None:
    write_event('start', nodeid)


def pytest_runtest_logfinish(nodeid: str, location: tuple) -> None:
    write_event('end', nodeid)


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    if report.failed:
        write_event('fail', report.nodeid)
