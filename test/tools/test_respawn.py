"""Respawner: back-off, its reset after a healthy run, the restart limit, what is not restarted."""
import pytest

from tlessbot_ros.tools.support.respawn import Respawner, RespawnPolicy, describe_exit


def crash_loop(respawner: Respawner, label: str, deaths: int, *, uptime_s: float = 1.0):
    """``deaths`` crashes in a row, each restarted when due; the delays asked for."""
    now, delays = 0.0, []
    for _ in range(deaths):
        decision = respawner.on_exit(label, -9, now=now, uptime_s=uptime_s)
        delays.append(decision.delay_s)
        if decision.delay_s is None:
            break
        assert respawner.due(now + decision.delay_s - 0.01) == []
        now += decision.delay_s
        assert respawner.due(now) == [label]
        respawner.restarted(label, now=now)
        now += uptime_s
    return delays


def test_the_back_off_doubles_up_to_its_maximum():
    respawner = Respawner(RespawnPolicy(delay_s=1.0, max_delay_s=5.0, max_restarts=100), ['a'])
    assert crash_loop(respawner, 'a', 5) == [1.0, 2.0, 4.0, 5.0, 5.0]


def test_a_healthy_run_starts_the_back_off_again():
    respawner = Respawner(RespawnPolicy(delay_s=1.0, healthy_s=60.0), ['a'])
    assert crash_loop(respawner, 'a', 3) == [1.0, 2.0, 4.0]
    assert respawner.on_exit('a', -9, now=1000.0, uptime_s=61.0).delay_s == 1.0


def test_too_many_restarts_within_the_window_give_up():
    policy = RespawnPolicy(delay_s=1.0, max_delay_s=1.0, max_restarts=3, window_s=100.0)
    respawner = Respawner(policy, ['a'])
    delays = crash_loop(respawner, 'a', 5)
    assert delays == [1.0, 1.0, 1.0, None]
    decision = respawner.on_exit('a', -9, now=10.0, uptime_s=1.0)
    assert decision.delay_s is None and 'restarted 3 times within 100 s' in decision.reason
    # the window slides: long after those restarts one more is allowed
    assert respawner.on_exit('a', -9, now=500.0, uptime_s=1.0).delay_s == 1.0


def test_processes_have_their_own_counts():
    respawner = Respawner(RespawnPolicy(), ['a', 'b'])
    crash_loop(respawner, 'a', 3)
    assert respawner.on_exit('b', -9, now=0.0, uptime_s=1.0).delay_s == 1.0


@pytest.mark.parametrize(('code', 'ever_ready', 'restarted'), [
    (-9, False, True),    # killed while it warmed up (OOM killer): worth another start
    (1, True, True),      # crashed after it was ready
    (1, None, True),      # a camera driver (no readiness): the camera may come back
    (1, False, False),    # a start-up error (bad parameter, missing model): would fail again
    (0, True, False),     # it ended by itself, not by a crash
])
def test_what_is_restarted(code, ever_ready, restarted):
    decision = Respawner(RespawnPolicy(), ['a']).on_exit('a', code, now=0.0, uptime_s=5.0,
                                                        ever_ready=ever_ready)
    assert (decision.delay_s is not None) == restarted
    assert bool(decision.reason) != restarted


def test_nothing_is_restarted_when_respawn_is_off():
    decision = Respawner(RespawnPolicy(enabled=False), ['a']).on_exit(
        'a', -9, now=0.0, uptime_s=5.0)
    assert decision.delay_s is None and decision.reason == 'respawn is off'


def test_diagnostics_name_restarts_and_exit_codes():
    respawner = Respawner(RespawnPolicy(), ['localiser', 'classifier'])
    assert respawner.diagnostic_values() == {}
    respawner.on_exit('localiser', -9, now=0.0, uptime_s=5.0)
    assert respawner.waiting('localiser')
    respawner.restarted('localiser', now=1.0, wall=0.0)
    assert not respawner.waiting('localiser')
    values = respawner.diagnostic_values()
    assert values['localiser.restarts'] == '1' and values['localiser.last_exit'] == '-9'
    assert 'localiser.last_restart' in values and 'classifier.restarts' not in values


@pytest.mark.parametrize('fields', [dict(delay_s=0.0), dict(delay_s=40.0, max_delay_s=30.0),
                                    dict(max_restarts=0), dict(window_s=0.0)])
def test_policy_rejects_nonsense(fields):
    with pytest.raises(ValueError):
        RespawnPolicy(**fields)


def test_exits_are_described_with_their_signal():
    assert describe_exit(-9) == 'code -9 (SIGKILL)'
    assert describe_exit(3) == 'code 3'
