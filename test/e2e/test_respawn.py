"""Each stage node killed with SIGKILL under `tlessbot launch` during a free-running looped
replay: launch starts it again, it is ready again, correct poses come again, and no pose is
wrong or stale (a frame of the dead process published late)."""
from __future__ import annotations

import pytest

from tlessbot_ros.data import DEFAULT_CLASSIFIER, DEFAULT_MODELS_INFO, DEFAULT_TEMPLATES
from tlessbot_ros.tools.support.models_info import load_symmetries
from tlessbot_ros.tools.support.processes import PERCEPTION_NODES
from tlessbot_ros.tools.support.respawn_trial import lockstep_reference, run_respawn_trial

# ~2.5 min here; each wait of the trial may take up to 10 min on a loaded machine
pytestmark = [pytest.mark.ros, pytest.mark.rosbag, pytest.mark.slow, pytest.mark.timeout(1800)]

PARAMS = [f'model_path:={DEFAULT_CLASSIFIER}', f'templates_path:={DEFAULT_TEMPLATES}',
          'workers.count:=1']   # a pose worker: it must not outlive its killed node


def test_every_stage_node_killed_comes_back_with_no_wrong_pose(moved_rig_bag):
    bag, config = moved_rig_bag
    symmetries = load_symmetries(DEFAULT_MODELS_INFO)
    reference = lockstep_reference(bag, config=config, symmetries=symmetries, params=PARAMS)
    trial = run_respawn_trial(bag, config=config, symmetries=symmetries,
                              reference_wrong=reference, params=PARAMS, timeout_s=600.0)
    output = trial.launch_output
    assert [kill.node for kill in trial.kills] == list(PERCEPTION_NODES)
    assert trial.baseline_wrong == 0 and trial.foreign_poses == 0
    for kill in trial.kills:
        assert kill.new_pid not in (None, kill.pid), kill
        assert f'[launch] {kill.node} exited with code -9 (SIGKILL); restarting it in 1.0 s' \
            in output
        assert f'[launch] {kill.node} restarted (exit -9), ready again in ' in output
        assert kill.next_correct_s is not None, kill   # correct poses of new frames again
        assert kill.wrong_poses == 0, kill
        assert kill.late_outputs == 0, kill            # nothing of the dead process, late
        assert kill.orphans == [], kill
        assert trial.launch_status[f'{kill.node}.restarts'] == '1'
        assert trial.launch_status[f'{kill.node}.last_exit'] == '-9'
    assert trial.kills[-1].children, 'the pose estimator had no worker to leave behind'
