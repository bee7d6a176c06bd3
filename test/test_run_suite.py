"""test/run_suite.py: a test that hangs costs one test, not the run; hanging twice fails it; an
abort at pytest's exit fails it, named."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

RUN_SUITE = Path(__file__).resolve().parent / 'run_suite.py'

SUITE = """
import os, time
from pathlib import Path

MARK = Path(__file__).with_name('hung_once')


def test_before():
    pass


def test_hangs_{when}():
    if {hang_again} or not MARK.exists():
        MARK.touch()
        time.sleep(600)   # ended by pytest-timeout's thread method, like a deadlock in C


def test_after():
    assert os.environ['TLESSBOT_TEST_JOURNAL']
"""


def _run(tmp_path: Path, hang_again: bool) -> subprocess.CompletedProcess:
    (tmp_path / 'test_suite.py').write_text(SUITE.format(
        when='twice' if hang_again else 'once', hang_again=hang_again))
    return subprocess.run(
        [sys.executable, str(RUN_SUITE), '-o', 'timeout=3', '-p', 'no:cacheprovider',
         '--rootdir', str(tmp_path), '-c', '/dev/null', str(tmp_path)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path)


def test_a_test_that_hangs_once_is_run_again_and_the_rest_still_runs(tmp_path):
    result = _run(tmp_path, hang_again=False)
    out = result.stdout + result.stderr
    assert result.returncode == 0, out
    assert 'test_hangs_once HUNG' in out and 'Timeout' in out   # the stacks are printed
    assert 'hung 1x, passed when run again' in out
    assert out.count('test_before') <= 2   # named in the hang report, never run again
    assert '1 deselected' in out and '2 passed' in out   # test_before kept out of the rerun


def test_a_test_that_hangs_twice_fails_the_run_and_the_rest_still_runs(tmp_path):
    result = _run(tmp_path, hang_again=True)
    out = result.stdout + result.stderr
    assert result.returncode == 1, out
    assert 'hung 2x, FAILED: hung twice' in out
    assert '1 passed, 2 deselected' in out   # test_after ran in the third process


ABORTS_AT_EXIT = """
import atexit, os


def test_passes_and_leaves_an_abort_for_the_exit():
    atexit.register(os.abort)   # as a thread cut off in C++ at interpreter exit does
"""


def test_an_abort_at_pytests_exit_fails_the_run_and_is_named(tmp_path):
    (tmp_path / 'test_suite.py').write_text(ABORTS_AT_EXIT)
    result = subprocess.run(
        [sys.executable, str(RUN_SUITE), '-p', 'no:cacheprovider', '--rootdir', str(tmp_path),
         '-c', '/dev/null', str(tmp_path)],
        capture_output=True, text=True, timeout=300, cwd=tmp_path)
    out = result.stdout + result.stderr
    assert result.returncode == 134, out   # 128 + SIGABRT, as a shell reports it
    assert '1 passed' in out and 'ended by SIGABRT after its last test ended' in out
    assert 'HUNG' not in out   # not taken for a hang, not run again
