"""tlessbot train: a one-batch fit (the kernel-map recipes) keeps its progress bar's elapsed time
moving, although the fit reports no progress until it ends."""
import time

from tlessbot_ros.tools.commands.train import _elapsed_shown


class _Bar:
    def __init__(self):
        self.redraws = 0

    def refresh(self):
        self.redraws += 1


def test_the_bar_is_redrawn_while_a_step_without_progress_runs_and_not_after():
    bar = _Bar()
    with _elapsed_shown(bar, every_s=0.02):
        deadline = time.monotonic() + 5.0
        while bar.redraws < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
    assert bar.redraws >= 3
    after = bar.redraws
    time.sleep(0.1)
    assert bar.redraws <= after + 1   # at most one redraw in flight when the block ended


def test_without_a_bar_nothing_is_redrawn():
    with _elapsed_shown(None, every_s=0.01):
        time.sleep(0.05)
