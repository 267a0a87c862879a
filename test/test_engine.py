"""
The loop engine and its timing model (engine.py, timing.py).

Also what the runtime does with late ticks and gaps (issue 9): offline, deterministic, seeded. No
ROS.
"""
from __future__ import annotations

import functools

from hybrid_force_controller.core.config.params import build_params
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.engine import LoopEngine
from hybrid_force_controller.core.offline.environment import ElasticSurface
from hybrid_force_controller.core.offline.scenario import PAPER_Q0, run_scenario, ScenarioConfig
from hybrid_force_controller.core.offline.simulator import ArmSimulator
from hybrid_force_controller.core.offline.timing import Schedule, Stall, TimingError, TimingModel
from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime, Mode
import numpy as np
import pytest


P = 1e-3


def engine(timing: TimingModel, horizon: float = 1.0, watchdog_action: str = 'zero',
           **overrides) -> LoopEngine:
    model = RobotModel.from_urdf()
    rt = ControllerRuntime(model, build_params(model, overrides))
    q0 = np.array(PAPER_Q0)
    p0 = model.kinematics(q0, np.zeros(2)).p_W
    sim = ArmSimulator(model, ElasticSurface.create(1700.0, p0, rt.params.law.n), q0, substeps=2)
    return LoopEngine(rt, sim, horizon, timing, watchdog_action=watchdog_action)


# ------------------------------------------------------------------ the timing model
@pytest.mark.parametrize('d', [0, 1, 3])
def test_lockstep_delay_is_exactly_d_periods(d):
    e = engine(TimingModel.lockstep(d), 0.2)
    log = e.run()
    assert log.ticks == e.steps  # one tick per plant step
    np.testing.assert_allclose(log.delays_s[d + 1:], d * P, atol=1e-9)


def test_a_controller_stall_skips_ticks_and_the_plant_holds_the_command():
    e = engine(TimingModel(stalls=(Stall('controller', 0.100, 0.030),)), 0.2)
    ticks, held = [], []
    while e.k < e.steps:
        e.step()
        if 0.101 <= e.t - P < 0.130:
            held.append(e.tau_plant.copy())
        ticks.append(len(e.outputs))
    ticks = np.array(ticks)
    assert ticks[101:130].sum() == 0 and ticks[130] == 1  # one late tick at the end
    assert np.all(np.array(held) == held[0])              # the plant kept the command


def test_the_states_sent_during_a_controller_stall_drain_oldest_first_after_it():
    """drain_per_ms 2: the 30 sent in a 30 ms stall reach it 0.5 ms apart; the newer queue."""
    sched = Schedule(TimingModel(stalls=(Stall('controller', 0.1, 0.03),), drain_per_ms=2.0), 1)
    ms = 1_000_000
    arrivals = [sched.state_arrival(k * ms) for k in range(100, 135)]
    assert arrivals[:30] == [130 * ms + k * ms // 2 for k in range(30)]  # oldest first
    assert arrivals[30:] == [k * ms for k in range(130, 135)]  # the engine's channel: FIFO
    assert Schedule(TimingModel(stalls=(Stall('controller', 0.1, 0.03),)), 1).state_arrival(
        100 * ms) == 130 * ms  # inf: all at the stall's end, the newest read


def test_a_plant_stall_publishes_nothing():
    e = engine(TimingModel(stalls=(Stall('plant', 0.100, 0.030),)), 0.2)
    stamps = []
    while e.k < e.steps:
        e.step()
        stamps.append(e.runtime.state_stamp)
    gaps = np.diff(stamps)
    assert gaps.max() == pytest.approx(0.031, abs=1e-9)  # the 30 ms without a state
    assert e.runtime.counters['stale_ticks'] >= 29       # ticks without a new state


def test_the_arms_watchdog_zeroes_the_effort_while_its_driver_stalls():
    """
    A 300 ms plant stall: the held command for command_timeout (0.1 s), then zero effort.

    The arm's firmware watchdog does not wait for its driver's process; before, the held
    command drove the paper's arm on for the whole stall.
    """
    e = engine(TimingModel(stalls=(Stall('plant', 0.100, 0.300),)), 0.5)
    held, zero = [], []
    while e.k < e.steps:
        e.step()
        t = e.t - P
        if 0.101 <= t < 0.199:
            held.append(e.tau_plant.copy())
        elif 0.202 <= t < 0.400:
            zero.append(e.tau_plant.copy())
    assert np.all(np.array(held) == held[0]) and np.abs(held[0]).max() > 1.0
    assert not np.any(zero) and e.command_timeouts == 1


def test_a_braking_watchdog_holds_the_arm_still_until_the_next_command():
    """
    Brake after command_timeout with ``watchdog_action='brake'``, until the next command.

    The plant holds the arm (no effort, no motion, as a Franka's reflex stops it); the
    first command after the stall releases it.
    """
    e = engine(TimingModel(stalls=(Stall('plant', 0.100, 0.300),)), 0.5, 'brake')
    braked, q_braked, released = [], [], False
    while e.k < e.steps:
        e.step()
        t = e.t - P
        if 0.202 <= t < 0.400:
            braked.append(e.tau_plant is None)
            q_braked.append(e.plant.q.copy())
        elif t >= 0.41:
            released |= e.tau_plant is not None
    assert all(braked) and e.command_timeouts == 1
    assert np.all(np.array(q_braked) == q_braked[0])  # held still through the stall
    assert released


def test_an_unknown_watchdog_action_is_refused():
    with pytest.raises(ValueError, match='watchdog_action must be one of'):
        engine(TimingModel(), 0.1, 'float')


def test_tick_on_state_ticks_once_per_state():
    log = engine(TimingModel(tick_on_state=True, latency=2e-4), 0.2).run()
    assert log.ticks == pytest.approx(200, abs=1)
    np.testing.assert_allclose(log.delays_s[2:], 2e-4, atol=1e-9)


def test_random_draws_repeat_with_the_seed():
    def delays(seed):
        return engine(TimingModel.ros_measured(seed=seed), 0.5).run().delays_s
    np.testing.assert_array_equal(delays(3), delays(3))
    assert not np.array_equal(delays(3), delays(4))


def test_measured_model_has_multi_millisecond_stalls():
    s = Schedule(TimingModel.ros_measured(seed=0), 20.0)
    lengths = np.array([b - a for a, b in s._stalls['controller']]) * 1e-9
    assert 40 <= lengths.size <= 120  # ~4 per second
    assert lengths.min() >= 1e-3 and lengths.max() <= 30e-3 and lengths.max() > 10e-3


@pytest.mark.parametrize('bad', [{'period': 0.0}, {'latency': -1e-3},
                                 {'stall_s': (2e-3, 1e-3)}, {'delay_steps': -1},
                                 {'stalls': (Stall('sim', 0.0, 0.01),)}, {'drain_per_ms': 0.0}])
def test_inconsistent_timing_is_rejected(bad):
    with pytest.raises(TimingError):
        TimingModel(**bad)


# ------------------------------------------------------------------ gaps and late ticks
@functools.lru_cache(maxsize=None)  # one run serves the tests that read it (none mutates it)
def hiccup_run(who: str, max_integration_dt: float | None = None, stall_periods: float = 10.0):
    stalls = tuple(Stall(who, t, 0.050) for t in (6.0, 7.0, 8.0))
    overrides = {'stall_periods': stall_periods}
    if max_integration_dt is not None:
        overrides['max_integration_dt'] = max_integration_dt
    return run_scenario(ScenarioConfig(theta_hat0_scale=0.5, duration=12.0, overrides=overrides,
                                       timing=TimingModel.ros_measured(seed=0, stalls=stalls)))


@pytest.mark.parametrize('who', ['controller', 'plant'])
def test_50_ms_gaps_leave_force_effort_and_theta_hat_calm(who):
    """
    Three 50 ms gaps (no ticks, or no inputs).

    The force stays within 0.05 N of f_d, no effort step beyond 0.5 N m, theta_hat within 1 % of
    the truth, no safe mode.
    """
    r = hiccup_run(who)
    w = r.t >= 5.5
    f = r.f_true_W[w] @ r.n_W
    assert np.abs(f - 1.0).max() <= 0.05
    assert np.abs(np.diff(r.tau[w], axis=0)).max() <= 0.5
    assert np.abs(r.theta_hat[w] / r.theta_true - 1.0).max() <= 0.01
    assert r.runtime.counters['safe_mode_entries'] == 0
    if who == 'controller':  # the node sees its own gaps: stalls, nothing integrated
        assert r.runtime.counters['stalls'] >= 3  # and the timing model's random ones
        # shorter than state_timeout, the command held throughout: no episode, adaptation on
        assert r.runtime.recovery.counts['stall'] == 0
    else:  # the plant's: late states, integrated clamped
        assert r.runtime.counters['late_states'] >= 3


def _excursion(r) -> float:
    w = r.t >= 5.5
    return float(np.abs(r.theta_hat[w] / r.theta_true - 1.0).max())


def test_clamping_the_integration_step_halves_the_theta_hat_excursion():
    """
    Negative control (stall detection off: a 50 ms gap is a late state).

    A late state allowed to integrate its whole gap moves theta_hat about twice as far.
    """
    clamped = hiccup_run('controller', stall_periods=1e6)
    free = hiccup_run('controller', 1.0, stall_periods=1e6)
    assert free.runtime.counters['late_states'] == 0
    assert clamped.runtime.counters['stalls'] == free.runtime.counters['stalls'] == 0
    assert _excursion(free) > 1.5 * _excursion(clamped)


def test_a_stall_integrates_nothing_across_it():
    """With stall detection (default), a 50 ms gap integrates nothing: less than clamped."""
    stalled, clamped = hiccup_run('controller'), hiccup_run('controller', stall_periods=1e6)
    assert stalled.runtime.counters['late_states'] < clamped.runtime.counters['late_states']
    assert _excursion(stalled) < _excursion(clamped)


def test_old_gains_fail_where_the_new_ones_hold():
    """
    Reproduce the real-time failure of the old defaults offline; the new defaults hold.

    The old defaults (K_D 200, adaptation on k_s e) fail with 2 ms one-way latency; the defaults
    hold there (10 ms margin).
    """
    timing = TimingModel.ros_measured(seed=0, latency=2e-3)
    for overrides, holds in (({'k_d': 200.0, 'k_a': 6000.0}, False), ({}, True)):
        r = run_scenario(ScenarioConfig(theta_hat0_scale=0.5, duration=8.0, timing=timing,
                                        overrides=overrides))
        f = r.f_true_W[r.t >= 5.0] @ r.n_W
        assert bool(np.abs(f - 1.0).max() <= 0.05) is holds, overrides
        assert (Mode.RUNNING == r.mode[-1]) or not holds
