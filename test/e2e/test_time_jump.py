"""Stamps that jump back: a simulated bag replayed in a loop without --restamp through the
three perception nodes (real processes). At every pass the stamps go back to the bag's first;
each node notices, restarts its synchronisation, reports the jump on /diagnostics, and the
poses of the later passes are as right as those of the first."""
from __future__ import annotations

import pytest

from tlessbot_ros.data import DEFAULT_MODELS_INFO
from tlessbot_ros.io.config import default_config_path
from tlessbot_ros.io.ground_truth import read_ground_truth
from tlessbot_ros.tools.cli import main
from tlessbot_ros.tools.support.bag_scoring import Estimate, frame_duplicates, score_frame
from tlessbot_ros.tools.support.graph_run import run_graph_on_bag
from tlessbot_ros.tools.support.models_info import load_symmetries
from tlessbot_ros.tools.support.processes import PERCEPTION_NODES
from tlessbot_ros.tools.support.rig import load_rig

pytestmark = [pytest.mark.ros, pytest.mark.rosbag, pytest.mark.slow]

FPS = 2.0
FRAMES = 4
SPAN_S = (FRAMES - 1) / FPS   # each new pass starts this far back
PASSES = 4
# The bag is replayed at half its rate: free-running, a frame that finds the graph busy is
# dropped whole at the entrance (by design), and at the bag's 2 frames/s a loaded CI host
# answered 3 frames of the later passes where 4 are asked for. The subject is the jumps.
REPLAY_RATE = 0.5


@pytest.fixture(scope='module')
def bag(tless_models_dir, tmp_path_factory):
    root = tmp_path_factory.mktemp('time_jump')
    assert main(['simulate', '--models', str(tless_models_dir), '--out', str(root / 'bop'),
                 '--bag', str(root / 'bag'), '--fps', str(FPS), '--frames', str(FRAMES),
                 '--seed', '4242', '--parts-min', '3', '--parts-max', '5',
                 '--cloud-stride', '4', '--no-masks', '--no-progress']) == 0
    return root / 'bag'


def _passes(run) -> list[dict[int, int]]:
    """Per pass of the loop: {frame stamp: when it was published (ns)}."""
    passes: list[dict[int, int]] = []
    for stamp, sent_ns in zip(run.frames_replayed, run.frames_replayed_at_ns):
        if not passes or stamp in passes[-1]:
            passes.append({})
        passes[-1][stamp] = sent_ns
    return passes


def _score(run, truth, symmetries, rig) -> list[dict[int, dict]]:
    """Per pass, {stamp: score} of the frames the graph answered in that pass: a pose
    belongs to the pass in which its frame was last published before the pose arrived."""
    passes = _passes(run)
    scored: list[dict[int, dict]] = [{} for _ in passes]
    for index, sent in enumerate(passes):
        for stamp, sent_ns in sent.items():
            next_ns = next((later[stamp] for later in passes[index + 1:] if stamp in later),
                           None)
            estimates = [Estimate(p.stamp_ns, p.obj_id, p.T, p.frame_id) for p in run.poses
                         if p.stamp_ns == stamp and p.received_ns >= sent_ns
                         and (next_ns is None or p.received_ns < next_ns)]
            if not estimates:
                continue
            matches, extra = score_frame(truth[stamp], estimates, symmetries)
            scored[index][stamp] = {'parts': len(matches),
                                    'correct': sum(m.correct for m in matches),
                                    'false_positives': len(extra),
                                    'duplicates': frame_duplicates(estimates, rig)}
    return scored


def test_a_looped_bag_without_restamp_keeps_its_poses_right(bag):
    config = default_config_path()
    run = run_graph_on_bag(bag, config=config, loop=True, restamp=False, rate=REPLAY_RATE,
                           duration_s=(PASSES * (SPAN_S + 1 / FPS) - 0.25) / REPLAY_RATE,
                           startup_timeout_s=600.0)
    # every node is alive (run_graph_on_bag raises when one exits) and saw the jumps
    for node in PERCEPTION_NODES:
        values = run.diagnostics[node]
        # the whole record as one string: pytest cuts a tuple's dict short
        assert int(values['time_jumps']) >= 1, f'{node}: {sorted(values.items())}'
        assert -SPAN_S - 0.01 <= float(values['last_time_jump_s']) < -0.1, (node, values)
        # the bag's stamps (2023) are not measured as an input age of years
        assert 'input_age_ms_p50' not in values, (node, values)
        assert float(values['stamp_offset_s']) > 86_400, (node, values)
        assert int(values['other_clock_frames']) >= 1, (node, values)
    truth = read_ground_truth(bag)
    scored = _score(run, truth, load_symmetries(DEFAULT_MODELS_INFO), load_rig(config))
    assert len(scored) >= 3, run.frames_replayed
    first, later = scored[0], [frame for p in scored[1:] for frame in p.items()]
    assert first and len(later) >= FRAMES, scored     # the graph answers after the jumps
    # After each jump the bag's first frames are answered again (none is lost to the jump).
    opening = sorted(_passes(run)[0])[:2]
    assert any(stamp in answered for answered in scored[1:] for stamp in opening), scored
    for stamp, frame in later:
        assert frame['duplicates'] == 0, (stamp, frame)
        if stamp in first:   # as right as in the first pass (free-running: one part of slack)
            assert frame['correct'] >= first[stamp]['correct'] - 1, (stamp, frame, first)
            assert frame['false_positives'] <= first[stamp]['false_positives'] + 1, \
                (stamp, frame, first)
    recall = (sum(f['correct'] for _, f in later) /
              max(1, sum(f['parts'] for _, f in later)))
    first_recall = (sum(f['correct'] for f in first.values()) /
                    max(1, sum(f['parts'] for f in first.values())))
    assert recall >= 0.9 * first_recall and recall >= 0.6, (scored, recall, first_recall)
