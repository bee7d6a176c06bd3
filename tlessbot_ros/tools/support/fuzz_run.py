"""Garbage at rate through the running graph, and what became of the good frames (bench fuzz,
its CI test).

A good bag is replayed in a loop (stamps shifted to now) through the three perception nodes
(:func:`~tlessbot_ros.tools.support.graph_run.run_graph_on_bag`); after a clean phase a
separate process publishes garbage on every input topic
(:mod:`~tlessbot_ros.tools.support.garbage`) for a while, then the replay goes on clean. The
good frames of each phase are scored against the bag's ground truth.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tlessbot_ros.core.common import Symmetries
from tlessbot_ros.errors import TlessbotError
from tlessbot_ros.io.ground_truth import read_ground_truth
from tlessbot_ros.tools.support.graph_run import GraphRunResult, run_graph_on_bag

PHASES = ('clean', 'garbage', 'after')
NODE_COUNTERS = ('frames', 'failures', 'dropped', 'malformed', 'zero_stamps')


@dataclass
class FuzzRun:
    """A graph run with garbage in its middle: the run, when the garbage started and ended
    (wall clock ns), what was sent, and each node's /diagnostics when it started."""

    result: GraphRunResult
    clean_ended_ns: int = 0   # when the garbage process was started
    garbage_started_ns: int = 0
    garbage_ended_ns: int = 0
    sent: dict = field(default_factory=dict)
    diagnostics_before: dict[str, dict[str, str]] = field(default_factory=dict)
    garbage_output: str = ''


@dataclass
class PhaseScore:
    """Good frames of one phase: replayed, answered (a pose came back), parts >= 30 % visible
    scored, and those within 5 cm / 5 deg."""

    frames: int = 0
    answered: int = 0
    parts: int = 0
    correct: int = 0
    answered_parts: int = 0     # parts of the answered frames ...
    answered_correct: int = 0   # ... and those within 5 cm / 5 deg

    @property
    def answered_share(self) -> float:
        return self.answered / self.frames if self.frames else float('nan')

    @property
    def recall(self) -> float:
        return self.correct / self.parts if self.parts else float('nan')

    @property
    def answered_recall(self) -> float:
        """Parts right among the frames answered: whether the answers that came are right."""
        return self.answered_correct / self.answered_parts if self.answered_parts else \
            float('nan')


def run_fuzz(bag: str, *, config: Path, ros_args: list[str], fps: float, clean_s: float,
             garbage_s: float, after_s: float, rate_hz: float = 100.0,
             frame_rate_hz: float = 1.0, huge_period_s: float = 1.0) -> FuzzRun:
    """Replay ``bag`` at ``fps`` frames/s for ``clean_s`` + garbage (its process's start-up,
    then ``garbage_s``) + ``after_s`` seconds; garbage at ``rate_hz`` per topic.

    Raises:
        TlessbotError: a node exited (run_graph_on_bag), or the garbage process failed.
    """
    from tlessbot_ros.tools.commands.bench.graph import bag_frame_interval_s

    fuzz = FuzzRun(GraphRunResult())
    lines: list[str] = []
    command = [sys.executable, '-m', 'tlessbot_ros.tools.support.garbage',
               '--duration', str(garbage_s), '--rate', str(rate_hz),
               '--frame-rate', str(frame_rate_hz), '--huge-period', str(huge_period_s),
               '--bag', str(bag)]
    process: list[subprocess.Popen] = []

    def read_output(pipe) -> None:
        for line in pipe:
            lines.append(line)
            if line.startswith('{"started_ns"'):
                fuzz.garbage_started_ns = json.loads(line)['started_ns']
                fuzz.diagnostics_before = {k: dict(v) for k, v in
                                           fuzz.result.diagnostics.items()}

    def start(result: GraphRunResult):
        fuzz.result = result
        thread = threading.Thread(target=_delayed_start, daemon=True,
                                  args=(clean_s, command, process, read_output, fuzz))
        thread.start()

        def stop() -> None:
            thread.join()
            if process:
                try:
                    process[0].wait(timeout=garbage_s + 60.0)
                except subprocess.TimeoutExpired:
                    process[0].kill()
                    process[0].wait()
        return stop

    # The garbage process needs a few seconds to start (imports, discovery) before garbage_s.
    startup_s = 8.0
    try:
        result = run_graph_on_bag(
            bag, config=config, rate=fps * bag_frame_interval_s(bag), loop=True,
            duration_s=clean_s + startup_s + garbage_s + after_s, restamp=True,
            settle_s=3.0, ros_args=ros_args, alongside=start)
    finally:
        if process and process[0].poll() is None:
            process[0].kill()
            process[0].wait()
    fuzz.result = result
    fuzz.garbage_output = ''.join(lines)
    for line in lines:
        if line.startswith('{"ended_ns"'):
            fuzz.sent = json.loads(line)
            fuzz.garbage_ended_ns = fuzz.sent['ended_ns']
    if not fuzz.garbage_started_ns or not fuzz.garbage_ended_ns:
        raise TlessbotError('the garbage publisher did not run:\n' + fuzz.garbage_output[-2000:])
    return fuzz


def _delayed_start(delay_s: float, command: list[str], process: list, read_output,
                   fuzz: FuzzRun) -> None:
    time.sleep(delay_s)   # the clean phase: a wall-clock span, not a synchronisation
    fuzz.clean_ended_ns = time.time_ns()
    process.append(subprocess.Popen(command, stdout=subprocess.PIPE, text=True,
                                    env=dict(os.environ)))
    read_output(process[0].stdout)


def phase_of(stamp_ns: int, fuzz: FuzzRun, recovery_s: float = 0.0,
             warm_s: float = 0.0) -> str:
    """Which phase a good frame (restamped: its stamp is when it was sent) belongs to ('' for
    the first ``warm_s`` of the replay, the garbage process's start-up and the first
    ``recovery_s`` after the garbage, which count for none)."""
    if stamp_ns < fuzz.result.replay_start_ns + int(warm_s * 1e9):
        return ''
    if stamp_ns >= fuzz.garbage_ended_ns + int(recovery_s * 1e9):
        return 'after'
    if stamp_ns >= fuzz.garbage_ended_ns:
        return ''
    if stamp_ns >= fuzz.garbage_started_ns:
        return 'garbage'
    return 'clean' if stamp_ns < fuzz.clean_ended_ns else ''


def score_phases(fuzz: FuzzRun, bag: str, symmetries: dict[int, Symmetries],
                 recovery_s: float = 0.0, warm_s: float = 0.0) -> dict[str, PhaseScore]:
    """Score the good frames of each phase against the bag's ground truth. A looped, restamped
    bag replays its frames in order, so the i-th side colour frame sent is the bag's frame
    i mod n. Frames sent in the replay's first ``warm_s`` or in the first ``recovery_s`` after
    the garbage are not scored."""
    from tlessbot_ros.tools.support.bag_scoring import Estimate, score_frame

    truth = read_ground_truth(bag)
    originals = sorted(truth)
    estimates: dict[int, list[Estimate]] = {}
    for pose in fuzz.result.poses:
        estimates.setdefault(pose.stamp_ns, []).append(
            Estimate(pose.stamp_ns, pose.obj_id, pose.T, pose.frame_id))
    scores = {phase: PhaseScore() for phase in PHASES}
    for index, stamp in enumerate(fuzz.result.frames_replayed):
        phase = phase_of(stamp, fuzz, recovery_s, warm_s)
        if not phase:
            continue
        score = scores[phase]
        found = estimates.get(stamp, [])
        matches, _ = score_frame(truth[originals[index % len(originals)]], found, symmetries)
        score.frames += 1
        score.answered += bool(found)
        score.parts += len(matches)
        score.correct += sum(m.correct for m in matches)
        if found:
            score.answered_parts += len(matches)
            score.answered_correct += sum(m.correct for m in matches)
    return scores


def answered_timeline(fuzz: FuzzRun) -> str:
    """One character per good frame sent, in order: 'A' answered, '-' not; '|' marks where the
    garbage started and ended (what a failed assertion prints, to tell a slow host from a
    graph that stopped answering)."""
    answered = {pose.stamp_ns for pose in fuzz.result.poses}
    marks: list[str] = []
    previous = 0
    for stamp in fuzz.result.frames_replayed:
        for edge in (fuzz.garbage_started_ns, fuzz.garbage_ended_ns):
            if previous < edge <= stamp:
                marks.append('|')
        marks.append('A' if stamp in answered else '-')
        previous = stamp
    return ''.join(marks)


def sample_at(fuzz: FuzzRun, samples: list, wall_ns: int):
    """The last 1 Hz sample taken before ``wall_ns`` (the first one when none was)."""
    offset_s = (wall_ns - fuzz.result.replay_start_ns) / 1e9
    index = int(np.searchsorted(np.asarray(fuzz.result.sample_times_s), offset_s)) - 1
    return samples[max(0, min(index, len(samples) - 1))]


def garbage_samples(fuzz: FuzzRun, samples: list) -> list:
    """The 1 Hz samples taken while garbage was published."""
    start = (fuzz.garbage_started_ns - fuzz.result.replay_start_ns) / 1e9
    end = (fuzz.garbage_ended_ns - fuzz.result.replay_start_ns) / 1e9
    return [v for t, v in zip(fuzz.result.sample_times_s, samples) if start <= t <= end]
