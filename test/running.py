"""A child process in a test: its output read as it comes, so a test waits for a line (not a
fixed sleep), and Ctrl-C sent as a terminal sends it (importable as ``from running import``)."""
from __future__ import annotations

import os
import signal
import subprocess
import threading
import time
from collections.abc import Sequence


class Running:
    """``argv`` started in its own process group, stdout and stderr merged into :attr:`lines`."""

    def __init__(self, argv: Sequence[str], *, env: dict[str, str] | None = None) -> None:
        self.argv = list(argv)
        self.process = subprocess.Popen(self.argv, stdout=subprocess.PIPE,
                                        stderr=subprocess.STDOUT, text=True, env=env,
                                        start_new_session=True)
        self.lines: list[str] = []
        self._changed = threading.Condition()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            with self._changed:
                self.lines.append(line)
                self._changed.notify_all()
        with self._changed:
            self._changed.notify_all()

    @property
    def output(self) -> str:
        with self._changed:
            return ''.join(self.lines)

    def wait_for(self, text: str, timeout_s: float = 120.0, *, count: int = 1) -> bool:
        """Whether ``count`` output lines holding ``text`` came within ``timeout_s`` (False
        early when the process ended without them)."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while sum(text in line for line in self.lines) < count:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not self._reader.is_alive():
                    return False
                self._changed.wait(min(remaining, 1.0))
        return True

    def interrupt(self, timeout_s: float = 60.0) -> int | None:
        """Ctrl-C: SIGINT to the whole process group (the process and its children), as a
        terminal sends it. Returns the exit code (None: still running after ``timeout_s``;
        the group is then killed)."""
        self.signal_group(signal.SIGINT)
        return self.wait(timeout_s)

    def signal_group(self, signum: int) -> None:
        if self.process.poll() is None:
            try:
                os.killpg(self.process.pid, signum)
            except ProcessLookupError:
                pass

    def wait(self, timeout_s: float = 60.0) -> int | None:
        """The exit code once the process ended (None: still running after ``timeout_s``;
        the group is then killed)."""
        try:
            code = self.process.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.signal_group(signal.SIGKILL)
            self.process.wait(timeout=10)
            code = None
        self._reader.join(timeout=10)
        return code

    def kill(self) -> None:
        self.signal_group(signal.SIGKILL)
        self.wait(10)


def unclean_lines(output: str) -> list[str]:
    """Lines of a process's output that a clean shutdown must not print: tracebacks, errors,
    logging that failed because the ROS context was gone."""
    bad = ('Traceback', '[ERROR]', 'ERROR:', 'Failed to publish', 'context is invalid',
           'exited with code')
    return [line for line in output.splitlines() if any(text in line for text in bad)]
