"""
Recovery from stalls and drops (issue 16), offline through the loop engine.

The runtime runs against the simulated arm with this machine's real-time timing model
(``TimingModel.ros_measured``, fixed seeds), the masses 50 % off and the plant's command
watchdog (0.1 s, zero effort, as the sim's ``command_timeout``), so a controller stall longer
than the watchdog drops the arm onto the surface, as on a torque-controlled robot. The same
freezes over DDS are in test_realtime_stalls.py; the exact figures come from
``bench --ros --freezes``.
"""
from __future__ import annotations

from helpers.offline import move_surface
from hybrid_force_controller.core.config.params import build_params
from hybrid_force_controller.core.offline.engine import Event
from hybrid_force_controller.core.offline.environment import sensor_wrench_from_f_W
from hybrid_force_controller.core.offline.scenario import PAPER_Q0, run_scenario, ScenarioConfig
from hybrid_force_controller.core.offline.timing import Stall, TimingModel
from hybrid_force_controller.core.runtime.catch_up import (CatchUp, CAUGHT_UP_PERIODS,
                                                           PLATEAU_PERIODS)
from hybrid_force_controller.core.runtime.controller_runtime import (ControllerRuntime, Mode,
                                                                     SILENT_STALLS)
from hybrid_force_controller.core.runtime.recovery import (Recovery, RecoveryConfig,
                                                           RecoveryConfigError, SETTLE_AFTER_S)
from hybrid_force_controller.tools.recovery_figures import (recovery_figures, settle_time,
                                                            theta_steady)
import numpy as np
import pytest


T_FREEZE = 6.0  # calm in contact by then (trusted theta_hat)
F_D = 1.0


def freeze_run(ms: float, seed: int = 0, overrides: dict | None = None, events=(),
               duration: float = T_FREEZE + 7.0):
    stalls = (Stall('controller', T_FREEZE, ms * 1e-3),)
    timing = TimingModel.ros_measured(seed=seed, stalls=stalls, tick_on_state=True)
    return run_scenario(ScenarioConfig(theta_hat0_scale=0.5, duration=duration, timing=timing,
                                       overrides=overrides or {}, events=events))


def figures(r, t_release: float) -> dict[str, float]:
    return recovery_figures(r.t, r.f_true_W @ r.n_W, T_FREEZE, t_release, F_D, r.t, r.theta_hat)


# ------------------------------------------------------------------ freezes (targets)
@pytest.mark.parametrize('ms,seed', [(150.0, 0), (300.0, 1), (500.0, 2)])
def test_a_freeze_longer_than_the_watchdog_recovers_within_the_targets(ms, seed):
    """
    The arm falls while the torque is off; after the release (issue 16's targets).

    Force back within 0.1 N of f_d (held 0.2 s) in <= 1 s, theta_hat within 10 % over 6 s,
    force RMS over [2 s, 6 s] <= 0.05 N. The stall is one episode; nothing integrates across it.
    """
    r = freeze_run(ms, seed)
    fig = figures(r, T_FREEZE + ms * 1e-3)
    assert fig['peak_force_n'] > 5.0, fig  # the watchdog cut the torque: the arm fell
    assert fig['back_s'] <= 1.0, fig
    assert fig['theta_change'] <= 0.10, fig
    assert fig['rms_force_error_n'] <= 0.05, fig
    assert r.runtime.recovery.counts['stall'] >= 1 and r.runtime.recovery.has_trusted


def test_without_episodes_the_same_freeze_throws_theta_hat():
    """Negative control: with ``episode_recovery`` off, a 500 ms freeze throws theta_hat."""
    fig = figures(freeze_run(500.0, 2, {'episode_recovery': False}), T_FREEZE + 0.5)
    assert fig['theta_change'] > 0.5, fig


def early_hiccups_run(recovery: bool, seed: int = 0):
    """
    Run the paper's scenario with the whole machine stalled 300 ms three times in 2.4 s.

    theta_hat starts at (2, 2/3) times the truth, as the sim's masses are off in the real-time
    tests: nothing is trusted yet when the hiccups come. The CI failure of 2026-12-03.
    """
    stalls = tuple(Stall(who, t, 0.3) for t in (0.5, 1.3, 2.1) for who in ('controller', 'plant'))
    timing = TimingModel.ros_measured(seed=seed, stalls=stalls, tick_on_state=True)
    return run_scenario(ScenarioConfig(theta_hat0_scale=(2.0, 2.0 / 3.0), duration=10.0,
                                       timing=timing, overrides={'episode_recovery': recovery}))


@pytest.mark.parametrize('recovery', [True, False])
def test_hiccups_before_theta_hat_is_trusted_do_not_throw_it(recovery):
    """
    A stall longer than state_timeout met in the force loop holds theta_hat (provisional).

    theta_hat stays within its start-up range (the start and the truth, 5 % margin) and ends
    within 1 % of the truth, the force within 0.05 N RMS over the last 3 s. Negative control:
    without episodes the falls throw theta_hat 28 % past its start.
    """
    r = early_hiccups_run(recovery)
    bound = 1.05 * np.maximum(r.theta_hat[0], r.theta_true)
    within = bool(np.all(r.theta_hat <= bound))
    assert within is recovery, (r.theta_hat.max(axis=0), bound)
    if recovery:
        f = r.f_true_W[r.t > 7.0] @ r.n_W
        np.testing.assert_allclose(r.theta_hat[-1], r.theta_true, rtol=0.01)
        assert np.sqrt(np.mean((f - F_D) ** 2)) <= 0.05
        assert r.runtime.counters['stalls'] >= 3  # the node saw the hiccups


# ------------------------------------------------------------------ the approach
def _corrupt_theta(scale: float):
    """Event action: theta_hat jumps to ``scale`` times the truth (a run-away, as in the issue)."""
    def act(runtime, _plant):
        runtime.ctrl.theta_hat = scale * runtime.model.theta_nominal
    return act


@pytest.mark.parametrize('recovery,regained', [(True, True), (False, False)])
def test_a_theta_hat_wrong_along_n_does_not_hold_the_approach_off(recovery, regained):
    """
    theta_hat 2.6 times too heavy, then the surface drops 3 cm (contact lost).

    The contact loss is an episode: theta_hat takes the trusted estimate and the approach
    reaches the surface in <= 1.5 s. Without episodes the over-compensated gravity holds the
    tool off: the search ends in no_surface (its reference moved the whole approach_limit).
    """
    events = [Event(T_FREEZE, _corrupt_theta(2.6)), Event(T_FREEZE, move_surface(0.03))]
    r = freeze_run(0.0, 0, {'episode_recovery': recovery}, events, duration=T_FREEZE + 4.0)
    back = r.in_contact & (r.t > T_FREEZE + 0.1)
    assert bool(back.any() and r.t[np.argmax(back)] <= T_FREEZE + 1.5) is regained
    assert (Mode.NO_SURFACE in r.mode) is not regained


@pytest.mark.parametrize('scale', [0.5, 2.6, 8.0])
def test_the_approach_ends_in_a_bounded_time_whatever_theta_hat(scale):
    """
    From start-up (no trusted estimate), an approach ends by limit / speed + 0.5 s.

    On the surface or in no_surface: its reference moves in absolute terms.
    """
    r = run_scenario(ScenarioConfig(theta_hat0_scale=scale, duration=4.0,
                                    timing=TimingModel.ros_measured(seed=0)))
    bound = 0.05 / 0.025 + 0.5  # approach_limit / approach_speed + 0.5 s (defaults)
    late = [m for t, m in zip(r.t, r.mode) if t > bound]
    assert Mode.APPROACH not in late


def test_a_freeze_during_an_approach_ends_on_the_surface():
    """The surface drops 3 cm; 0.4 s into the approach a 300 ms freeze: on it 1.5 s after."""
    stalls = (Stall('controller', T_FREEZE + 0.4, 0.3),)
    timing = TimingModel.ros_measured(seed=3, stalls=stalls, tick_on_state=True)
    r = run_scenario(ScenarioConfig(theta_hat0_scale=0.5, duration=T_FREEZE + 4.0,
                                    timing=timing, events=[Event(T_FREEZE,
                                                                 move_surface(0.03))]))
    release = T_FREEZE + 0.7
    back = r.in_contact & (r.t > release)
    assert back.any() and r.t[np.argmax(back)] <= release + 1.5
    assert r.in_contact[r.t > release + 2.0].all()


@pytest.mark.parametrize('drain', [1.5, 2.0, 3.0])
def test_a_freeze_in_an_approach_with_its_backlog_replayed_ends_on_the_surface(drain):
    """
    As above, with the states sent during the freeze read oldest first, ``drain`` per ms.

    (C1): nothing is sent until both inputs are current (the plant keeps its watchdog's zero
    effort meanwhile), then the safe hold. Before, the hold ran on those old states with the
    weight of the arm while the fall pressed it into the surface: flung off it, not found
    again within 3 s, in each of these (docs/results.md section 30).
    """
    stalls = (Stall('controller', T_FREEZE + 0.4, 0.3),)
    timing = TimingModel.ros_measured(seed=0, stalls=stalls, tick_on_state=True,
                                      drain_per_ms=drain)
    r = run_scenario(ScenarioConfig(theta_hat0_scale=0.5, duration=T_FREEZE + 4.0,
                                    timing=timing, events=[Event(T_FREEZE,
                                                                 move_surface(0.03))]))
    release = T_FREEZE + 0.7
    after = r.t > release
    out = after & np.array([m != Mode.SAFE for m in r.mode])
    t_out = r.t[np.argmax(out)]  # the hold's dwell done: out of safe mode
    silent = after & (r.t < t_out - 0.06)  # the hold is 50 ms, its command 0-1 ms late
    assert np.all(r.in_contact[r.t > release + 2.0])
    assert t_out - release > 0.1 and not np.any(r.tau[silent])  # the plant's zero effort
    f = r.f_true_W @ r.n_W
    assert f[r.t > t_out + 0.1].max() < 20.0  # the fall's 53 N was before, at zero effort


# ------------------------------------------------------------------ the bookkeeping
def _calm(rec: Recovery, t0: float, t1: float, theta: np.ndarray, df: float = 0.0,
          e: float = 0.0, loop: bool = True) -> None:
    """Note ticks every 10 ms over [t0, t1) with the same errors and theta_hat."""
    for t in np.arange(t0, t1 - 1e-9, 0.01):
        rec.note(float(t), df, e, loop, theta)


def test_after_a_stall_the_hold_starts_from_a_current_state_not_a_fresh_one(model):
    """
    Over DDS the first state after a 300 ms freeze was 92 ms old (fresh), the next current.

    Nothing is sent at the first; the hold starts from the current one, the arm 3 cm (0.03
    rad) further: its effort stays that of the weight. Latched on the old state, the hold
    pulled the arm back to it at the effort limits (-100 N m, the flight log of the run).
    """
    rt, names = ControllerRuntime(model, build_params(model)), list(model.joint_names)
    q0 = np.array(PAPER_Q0)
    F = sensor_wrench_from_f_W(model.kinematics(q0, np.zeros(2)).R_W_ee, [0.0, -1.0, 0.0])

    def tick(t: float, q: np.ndarray, age: float):
        rt.on_joint_state(names, q, np.zeros(2), t - age, t)
        rt.on_wrench('tool0', F * (1.0 + 1e-3 * np.sin(t * 1e3)), t - age, t)  # not frozen
        return rt.tick(t)

    for k in range(200):
        before = tick(k * 1e-3, q0, 0.0)
    out = tick(0.499, q0, 0.092)  # after a 300 ms freeze (over SILENT_STALLS state_timeout)
    assert out.mode == Mode.SAFE and out.tau is None and 'catching up' in out.status
    out = tick(0.500, q0 + [0.03, 0.0], 0.0002)
    assert out.mode == Mode.SAFE and np.abs(out.tau - before.tau).max() < 5.0, out.tau


def test_a_stall_just_over_state_timeout_is_no_silence(model):
    """150 ms (under SILENT_STALLS = 2 state_timeout): the hold goes on being sent at once."""
    rt, names = ControllerRuntime(model, build_params(model)), list(model.joint_names)
    q0 = np.array(PAPER_Q0)
    F = sensor_wrench_from_f_W(model.kinematics(q0, np.zeros(2)).R_W_ee, [0.0, -1.0, 0.0])
    for k in range(201):
        t = 0.35 if k == 200 else k * 1e-3  # the last after a 151 ms stall
        rt.on_joint_state(names, q0, np.zeros(2), t, t)
        rt.on_wrench('tool0', F * (1.0 + 1e-3 * np.sin(k)), t, t)
        out = rt.tick(t)
    assert SILENT_STALLS == 2.0 and rt.last_stall_s > 0.15 and out.tau is not None


def test_a_catch_up_ends_once_each_input_was_current_since_it_began():
    """(C1): two streams in different phases; a silent one stays silent until it ends."""
    c, P = CatchUp(), 1e-3
    c.begin(silent=True)
    assert not c.done(0.0, 0.050, 0.001, P, 0.1) and c.silent  # the wrench was current
    c.begin(silent=False)  # stale again: begins anew, still silent
    assert not c.done(0.001, 0.002, 0.030, P, 0.1) and c.silent
    assert c.done(0.002, 0.030, 0.004, P, 0.1) and not c.active and not c.silent
    assert CAUGHT_UP_PERIODS == 5


def test_a_steady_lag_ends_a_catch_up_after_a_plateau_and_a_backlog_does_not():
    """
    (C1): 11.5 ms old for good (a lag learnt slowly): current after PLATEAU_PERIODS.

    A backlog draining (1 ms younger each 0.7 ms), a stream that stopped (older each tick)
    or one older than state_timeout is not.
    """
    P = 1e-3
    for ages, over_at in (([0.0115] * 30, PLATEAU_PERIODS),
                          ([0.09 - 3e-4 * k for k in range(30)], None),
                          ([0.02 + 1e-3 * k for k in range(30)], None),
                          ([0.12] * 30, None)):
        c = CatchUp()
        c.begin(silent=False)
        over = [k for k, age in enumerate(ages) if c.done(k * P, age, 0.0, P, 0.1)]
        assert (over[0] if over else None) == over_at, ages


def test_trusted_estimate_needs_a_calm_stretch_and_an_episode_holds_it():
    rec = Recovery(2, RecoveryConfig(calm_time=0.5))
    theta = np.array([1.0, 2.0])
    assert rec.begin('stall', 0.0, theta) is None  # not in the loop yet
    assert rec.counts['stall'] == 1 and not rec.frozen
    _calm(rec, 0.1, 0.7, theta)  # calm from t = 0.1: the episode ends at 0.6
    assert not rec.episode and not rec.has_trusted
    _calm(rec, 0.7, 1.21, theta)  # the window from 0.7 trusts its start at 1.2
    assert rec.has_trusted
    np.testing.assert_array_equal(rec.trusted, theta)
    held = rec.begin('force_transient', 1.3, 3 * theta)
    np.testing.assert_array_equal(held, theta)
    assert rec.frozen and rec.episode == 'force_transient'
    rec.begin('stall', 1.4, 3 * theta)
    assert rec.counts['stall'] == 1 and rec.episode == 'force_transient'  # one at a time
    rec.note(1.5, 0.0, 0.0, True, 2 * theta)
    assert rec.note(2.0, 0.0, 0.0, True, 2 * theta)  # 0.5 s calm: it ends
    np.testing.assert_array_equal(rec.trusted, theta)  # the episode's theta is not trusted


def test_a_theta_hat_thrown_in_one_tick_is_never_trusted():
    """A window trusts the estimate it began with: one the next tick brings must stay calm."""
    rec = Recovery(2, RecoveryConfig(calm_time=0.5))
    theta = np.array([1.0, 2.0])
    _calm(rec, 0.0, 0.6, theta)
    _calm(rec, 0.6, 0.9, 3 * theta)  # thrown at 0.6; the errors it causes come 0.3 s later
    assert rec.begin('contact_loss', 0.9, 3 * theta) is not None
    np.testing.assert_array_equal(rec.trusted, theta)


def test_before_trust_a_broken_loop_holds_theta_hat_until_settled():
    """
    Safe mode met in the force loop with nothing trusted: theta_hat holds (provisional).

    It ends after calm_time settled (errors below the episode thresholds, not calm), and
    after SETTLE_AFTER_S in any case; an episode of the model's own making only counts.
    """
    rec = Recovery(2, RecoveryConfig(calm_time=0.5))
    theta = np.array([1.0, 2.0])
    _calm(rec, 0.0, 0.3, theta, df=0.5, e=0.1)  # in the loop, a model still wrong: not calm
    assert rec.begin('force_transient', 0.3, 2 * theta) is None and not rec.frozen
    held = rec.begin('safe_mode', 0.31, theta)
    np.testing.assert_array_equal(held, theta)
    assert rec.frozen and rec.provisional
    _calm(rec, 0.4, 0.89, theta, df=2.0, e=0.2)  # settled from 0.4, not calm
    assert rec.frozen
    assert rec.note(0.9, 2.0, 0.2, True, theta) and not rec.frozen and not rec.has_trusted
    rec.begin('stall', 1.0, theta)
    _calm(rec, 1.0, 1.0 + SETTLE_AFTER_S - 0.01, theta, df=5.0, e=0.3)  # never settled
    assert rec.frozen
    assert rec.note(1.0 + SETTLE_AFTER_S, 5.0, 0.3, True, theta) and not rec.frozen


def test_out_of_the_force_loop_a_broken_loop_only_counts_before_trust():
    rec = Recovery(2, RecoveryConfig(calm_time=0.5))
    _calm(rec, 0.0, 0.3, np.ones(2), loop=False)  # an approach
    assert rec.begin('safe_mode', 0.3, np.ones(2)) is None
    assert rec.counts['safe_mode'] == 1 and not rec.frozen


def test_an_episode_that_never_calms_ends_settled_after_settle_after_s():
    """A trusted estimate too wrong for calm must not freeze adaptation for good."""
    rec = Recovery(2, RecoveryConfig(calm_time=0.5))
    theta = np.array([1.0, 2.0])
    _calm(rec, 0.0, 0.51, theta)
    assert rec.has_trusted
    rec.begin('stall', 1.0, theta)
    _calm(rec, 1.0, 1.0 + SETTLE_AFTER_S, theta, df=0.5, e=0.1)  # settled, never calm
    assert rec.frozen
    _calm(rec, 1.0 + SETTLE_AFTER_S, 1.0 + SETTLE_AFTER_S + 0.51, theta, df=0.5, e=0.1)
    assert not rec.frozen


def test_new_projection_bounds_clip_the_trusted_estimate():
    rec = Recovery(2, RecoveryConfig(calm_time=0.0))
    for t in (0.0, 0.01):  # a window of calm_time 0 still needs the tick after its start
        rec.note(t, 0.0, 0.0, True, np.array([1.0, 5.0]))
    rec.configure(RecoveryConfig(), np.array([0.0, 0.0]), np.array([2.0, 3.0]))
    np.testing.assert_array_equal(rec.trusted, [1.0, 3.0])


@pytest.mark.parametrize('df,e,kind', [(3.5, 0.0, 'force_transient'),
                                       (0.0, 0.3, 'tracking_fault'), (2.9, 0.2, '')])
def test_transients_start_an_episode_at_the_next_tick(df, e, kind):
    rec = Recovery(1, RecoveryConfig())
    rec.note(0.0, df, e, True, np.ones(1))
    assert rec.triggered() == kind


def test_calm_is_in_contact_with_small_errors_only():
    rec = Recovery(1, RecoveryConfig(calm_time=0.1))
    for k, (df, e, loop) in enumerate([(0.25, 0.0, True), (0.0, 0.03, True), (0.0, 0.0, False)]):
        for j in range(20):
            rec.note(k + 0.01 * j, df, e, loop, np.ones(1))
        assert not rec.has_trusted


@pytest.mark.parametrize('bad', [{'stall_periods': 1.0}, {'calm_force': 5.0},
                                 {'calm_error': 0.3}, {'calm_time': float('nan')}])
def test_inconsistent_recovery_settings_are_refused(bad):
    with pytest.raises(RecoveryConfigError):
        RecoveryConfig(**bad)


def test_settle_time_needs_the_whole_hold():
    t = np.arange(0.0, 1.0, 0.01)
    f = np.where((t > 0.3) & (t < 0.4), 1.0, 5.0)  # in the band for 0.1 s only
    f[t >= 0.6] = 1.05
    assert settle_time(t, f, 0.0, 1.0, 0.1, 0.2) == pytest.approx(0.6)
    assert np.isnan(settle_time(t, f, 0.0, 1.0, 0.01, 0.2))


def test_theta_steady_needs_the_whole_span_within_the_tolerance():
    t = np.arange(0.0, 3.0, 0.01)
    theta = np.column_stack([np.ones_like(t), 2.0 + 0.05 * (t < 0.9)])
    assert theta_steady(t, theta, 2.0, 0.01)  # the step at 0.9 s is older than the span
    assert not theta_steady(t[:150], theta[:150], 2.0, 0.01)  # less than 2 s of samples
    assert not theta_steady(t, theta, 2.5, 0.01)  # the step is inside the span
