"""bench transport runs its four publisher/subscriber set-ups and reports each."""
from __future__ import annotations

import subprocess
import sys

import pytest

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def test_bench_transport_reports_four_setups():
    out = subprocess.run([sys.executable, '-m', 'tlessbot_ros.tools.cli', 'bench', 'transport',
                          '--fps', '5', '--duration', '2'],
                         capture_output=True, text=True, timeout=180)
    assert out.returncode == 0, out.stderr[-2000:]
    rows = [line for line in out.stdout.splitlines() if line.startswith('| ') and ' % |' in line]
    assert len(rows) == 4
    # every set-up delivered something at 5 fps (a set-up that failed to connect shows 0 %)
    assert all(not row.split('|')[2].strip().startswith('0 %') for row in rows), rows
