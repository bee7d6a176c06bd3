"""Garbage at rate (issue #21, item 5): malformed messages at 100 Hz on every input topic of
every stage while the demo bag flows through the three node processes; the nodes live on, do
not grow without bound, and still answer the good frames."""
from __future__ import annotations

import pytest

from tlessbot_ros.data import DEFAULT_MODELS_INFO
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.tools.support.defaults import DEFAULT_BAG
from tlessbot_ros.tools.support.fuzz_run import (
    answered_timeline,
    run_fuzz,
    sample_at,
    score_phases,
)
from tlessbot_ros.tools.support.models_info import load_symmetries

pytestmark = [pytest.mark.ros, pytest.mark.slow]

GARBAGE_S = 15.0
# A 100 Hz flood on a topic whose subscription keeps the last 2 messages (input_depth's default)
# overwrites a good message before a busy node's executor takes it (docs/bench/fuzz-at-rate.md: 5 %
# of the good frames answered); with 30 the history covers the executor's stalls. Under garbage
# fewer good frames are still answered (the garbage's callbacks take CPU from the stages, and a
# frame that waits too long is dropped at the entrance, as any late frame), so what is asserted
# is: the good frames are not silenced, the answers that come are right, and once the garbage
# stops the graph answers as before it.
INPUT_DEPTH = 30
# Garbage stamps years away from the good ones, one after the other on a topic, look like time
# jumps; each emptied every queue, and no good frame was answered. With jump confirmations a
# stray stamp is dropped instead (SyncParams.jump_confirmations; docs/bench/fuzz-at-rate.md). The
# localiser confirms with 4 by default; the later stages, behind its relay, do not (their
# inputs come from our nodes), but the garbage here reaches the relay topics too.
JUMP_CONFIRMATIONS = 4
# Good frames at 1 a second, half the demo's rate: the subject is garbage, not throughput. At 2
# a second CI's host (2026-12-04) answered 18 of 22 clean frames and 15 of 35 after the garbage,
# where a faster one answers all of them: frames that find the graph busy are dropped at the
# entrance, by the host's speed. The first seconds after the garbage are not scored: frames
# sent then still meet garbage queued in the DDS histories (INPUT_DEPTH deep).
GOOD_FPS = 1.0
RECOVERY_S = 3.0
# Nor are the replay's first seconds: in one fresh-clone CI run on a quiet host only 6 of the 13
# clean frames were answered (15 of 17 after the garbage), where other runs answer all of them.
WARM_S = 8.0
MIN_REFERENCE_ANSWERED = 4   # clean frames answered, at least
RIGHT_TOLERANCE = 0.15      # share of parts right in the answered frames, against clean
ANSWERED_TOLERANCE = 0.35   # share of good frames answered after the garbage, against clean
# RSS may grow while garbage flows (the allocator keeps freed buffers up to its trim threshold,
# 64 MiB, and DDS keeps its receive pools), but not by what a leak of the garbage would hold:
# one 4K image (16-24 MiB) a second kept would add 240 MiB or more in GARBAGE_S, and every
# garbage message kept (about 600 a second per node) more still.
# Measured 2026-12-02 under load average 9-10 (other work on both cores): the localiser grew by
# 207-253 MiB (more garbage is taken in while the stages are slow), so the bound is 300 MiB,
# still below what keeping the 4K garbage alone would add (20 of 16-24 MiB).
RSS_GROWTH_MIB = 300.0
# per process: the pose estimator's figure holds its worker process too, whose caches also fill
# as parts of new objects are fitted (with two jump confirmations every good frame of the
# garbage phase is answered: 1218 against 972 MiB measured)
PROCESSES = {'pose_estimator': 2}


@pytest.fixture(scope='module')
def fuzz_run():
    fuzz = run_fuzz(str(DEFAULT_BAG), config=default_config_path(), fps=GOOD_FPS,
                    ros_args=['-p', f'input_depth:={INPUT_DEPTH}',
                              '-p', f'sync.jump_confirmations:={JUMP_CONFIRMATIONS}'],
                    clean_s=14.0 + WARM_S, garbage_s=GARBAGE_S, after_s=14.0, rate_hz=100.0,
                    frame_rate_hz=1.0, huge_period_s=1.0)
    return fuzz, score_phases(fuzz, str(DEFAULT_BAG), load_symmetries(DEFAULT_MODELS_INFO),
                              RECOVERY_S, WARM_S)


def test_every_node_lives_and_counts_the_garbage(fuzz_run):
    fuzz, _ = fuzz_run   # run_fuzz raises when a node exits
    result = fuzz.result
    assert set(result.diagnostics) >= {'localiser', 'classifier', 'pose_estimator'}
    assert sum(fuzz.sent['per_topic'].values()) > 18 * GARBAGE_S   # garbage did flow
    for node, values in result.diagnostics.items():
        before = fuzz.diagnostics_before.get(node, {})
        assert int(values['malformed']) > int(before.get('malformed', 0)), (node, values)
        assert 'Traceback' not in result.node_output


def test_good_frames_are_still_answered_right(fuzz_run):
    fuzz, scores = fuzz_run
    clean, garbage, after = scores['clean'], scores['garbage'], scores['after']
    # what a failure prints: the scores, which frames were answered, each node's counters
    counters = {node: {key: values.get(key) for key in ('frames', 'dropped', 'malformed')}
                for node, values in fuzz.result.diagnostics.items()}
    evidence = (answered_timeline(fuzz), counters, scores)   # the short ones first
    assert clean.frames and garbage.frames and after.frames, evidence
    # the reference must hold answered frames to compare with; how many of them a host answers
    # at GOOD_FPS is its speed (7 of 14 on a CI run beside a second one), not the subject
    assert clean.answered >= MIN_REFERENCE_ANSWERED, evidence
    assert garbage.answered > 0, evidence
    assert garbage.answered_recall >= clean.answered_recall - RIGHT_TOLERANCE, evidence
    assert after.answered_share >= clean.answered_share - ANSWERED_TOLERANCE, evidence


def test_no_unbounded_growth(fuzz_run):
    fuzz, _ = fuzz_run
    result = fuzz.result
    for node, samples in result.rss_mb_samples.items():
        before = sample_at(fuzz, samples, fuzz.garbage_started_ns)
        after = sample_at(fuzz, samples, fuzz.garbage_ended_ns)
        assert after < before + RSS_GROWTH_MIB * PROCESSES.get(node, 1), (node, before, after)
        fds = result.fd_samples[node]
        assert sample_at(fuzz, fds, fuzz.garbage_ended_ns) <= \
            sample_at(fuzz, fds, fuzz.garbage_started_ns) + 5, node
