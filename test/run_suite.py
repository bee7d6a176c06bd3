"""Run the test suite so that a test that hangs below Python costs one test, not the run.

``make test`` runs this. A deadlock inside a C library (DDS, a BLAS or OpenMP pool) blocks the
main thread where pytest-timeout's signal never reaches it: the run then waits until CI's limit.
Here pytest-timeout uses its thread method: a test that runs past ``timeout`` (setup.cfg) gets
every thread's stack printed and the pytest process is ended. This script reads the journal the
test harness writes (conftest.py, ``TLESSBOT_TEST_JOURNAL``): the test that started and never
ended is the one that hung. It kills what that run left behind (its process group), then starts
pytest again on the tests not run yet, the hung one among them, once. A test that hangs twice
fails the run; every hang is listed at the end, with the stacks above it.

A pytest process that a signal ends after its last test (an abort at interpreter exit) fails
the run: it is reported, not run again.

Usage: ``python test/run_suite.py [pytest arguments]``; the exit status is pytest's (128 + the
signal's number when one ended it), or 1 when an earlier part of the run failed or a test hung
twice.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from suite_journal import JOURNAL_VARIABLE, read_events  # noqa: E402

MAX_RUNS = 10   # a suite that hangs this often is broken, not flaky
HERE = Path(__file__).resolve().parent


def read_journal(path: Path) -> tuple[set[str], list[str]]:
    """(failed test ids, ids of tests that started and never ended, in start order)."""
    events = read_events(path)
    ended = {n for e, n in events if e == 'end'}
    started = dict.fromkeys(n for e, n in events if e == 'start')
    return {n for e, n in events if e == 'fail'}, [n for n in started if n not in ended]


def run_pytest(args: list[str], journal: Path, domain_offset: int) -> int:
    """One pytest process in its own process group; what it leaves behind is killed."""
    python_path = os.pathsep.join(p for p in (str(HERE), os.environ.get('PYTHONPATH')) if p)
    env = dict(os.environ, **{JOURNAL_VARIABLE: str(journal), 'PYTHONPATH': python_path})
    if domain_offset and 'TLESSBOT_TEST_DOMAIN_ID' in env:   # leftovers cannot be heard
        env['TLESSBOT_TEST_DOMAIN_ID'] = str((int(env['TLESSBOT_TEST_DOMAIN_ID'])
                                              + domain_offset) % 100 + 1)
    process = subprocess.Popen([sys.executable, '-m', 'pytest', '-p', 'suite_journal',
                                '-o', 'timeout_method=thread', *args],
                               env=env, start_new_session=True)
    try:
        code = process.wait()
    except KeyboardInterrupt:
        os.killpg(process.pid, signal.SIGINT)
        process.wait()
        raise
    try:
        os.killpg(process.pid, signal.SIGKILL)   # children of a test ended mid-way
    except ProcessLookupError:
        pass
    return code


def main(args: list[str]) -> int:
    hangs: dict[str, int] = {}
    with tempfile.TemporaryDirectory(prefix='tlessbot-tests-') as folder:
        journal = Path(folder) / 'journal.jsonl'
        for run in range(MAX_RUNS):
            code = run_pytest(args, journal, run)
            failed, unfinished = read_journal(journal)
            if not unfinished:
                break
            hung = unfinished[-1]
            hangs[hung] = hangs.get(hung, 0) + 1
            print(f'\nrun_suite: {hung} HUNG (stacks above); pytest was ended.', flush=True)
            if hangs[hung] > 1:   # twice: a failure, and the rest of the suite still runs
                with journal.open('a') as out:
                    out.write(json.dumps(['end', hung]) + '\n' + json.dumps(['fail', hung]) + '\n')
            print('run_suite: the tests not run yet go on in a new pytest process\n', flush=True)
        else:
            print(f'run_suite: {MAX_RUNS} runs ended by hangs; giving up', flush=True)
            return 1
    for nodeid, count in hangs.items():
        outcome = ('FAILED: hung twice' if count > 1 else
                   'failed when run again' if nodeid in failed else 'passed when run again')
        print(f'run_suite: hung {count}x, {outcome}: {nodeid}', flush=True)
    if code == 5 and hangs:   # the last run had nothing left but what was deselected
        code = 0
    if code < 0:   # every test ended, then a signal ended pytest: it died at its exit
        print(f'run_suite: pytest was ended by {signal.Signals(-code).name} after its last '
              'test ended: a thread still in native code at interpreter exit?', flush=True)
        code = 128 - code   # the shell's status for a process a signal ended
    return code if code or not failed else 1


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
