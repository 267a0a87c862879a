"""Online stiffness estimate (core/stiffness.py): unit tests on synthetic data, then the
open-loop study on the existing closed loop (the estimator fed its logs). Fixed seeds."""
from __future__ import annotations

import dataclasses
import math
import tracemalloc

import numpy as np
import pytest

from hybrid_force_controller.core.filters import LowPassFilter
from hybrid_force_controller.core.params import CONTROLLER_SCHEMA
from hybrid_force_controller.core.stiffness import (STIFFNESS_SCHEMA, StiffnessConfig,
                                                    StiffnessConfigError, StiffnessError,
                                                    StiffnessEstimator,
                                                    stiffness_config_from_values)

DT = 1e-3
X0 = -1.6107  # surface position along n, m (the paper scenario's start height)
STIFFNESSES = (300.0, 500.0, 1700.0, 5000.0)


def synthetic(k: float, duration: float = 3.0, f_lo: float = 0.2, f_hi: float = 2.0,
              hz: float = 0.5, noise: float = 0.0, seed: int = 0,
              filter_hz: float = 200.0) -> tuple[np.ndarray, np.ndarray]:
    """(f_n filtered, x_n): a press oscillating between f_lo and f_hi on f = k (x - x0)."""
    t = np.arange(int(round(duration / DT))) * DT
    f_true = f_lo + (f_hi - f_lo) * 0.5 * (1.0 - np.cos(2 * np.pi * hz * t))
    x_n = X0 + f_true / k
    f_meas = f_true + np.random.default_rng(seed).normal(0.0, noise, t.size)
    filt = LowPassFilter(filter_hz, size=1)
    f_n = np.array([filt.update(np.array([f]), DT) and float(filt.value[0]) for f in f_meas])
    return f_n, x_n


def feed(est: StiffnessEstimator, f_n, x_n, contact=True) -> np.ndarray:
    contact = np.broadcast_to(contact, np.shape(f_n))
    return np.array([est.update(float(f), float(x), DT, bool(c))
                     for f, x, c in zip(f_n, x_n, contact)])


def make(**kw) -> StiffnessEstimator:
    return StiffnessEstimator(StiffnessConfig(enabled=True, **kw))


# ---------------------------------------------------------------- recovery
@pytest.mark.parametrize('filter_hz', [0.0, 200.0])
@pytest.mark.parametrize('k', STIFFNESSES)
def test_exact_recovery_noise_free(k, filter_hz):
    est = make(force_filter_hz=filter_hz)
    assert est.k_hat == 6000.0 and not est.valid  # the prior, before any data
    k_hat = feed(est, *synthetic(k, filter_hz=filter_hz))
    # exact up to the regulariser's pull, rho (k_hat0 - k) / sum (u - u_bar)^2 ~ 1e-6 k
    assert est.k_hat == pytest.approx(k, rel=1e-5)
    assert est.valid and est.k_hat_std < 1e-3 * k
    assert np.all(np.isfinite(k_hat))


def test_filter_lag_biases_unless_x_is_filtered_alike():
    """(S0): feeding a 50 Hz-filtered force with the filter switched off in the estimator
    (x_n unfiltered) biases k_hat; with the matching filter it is exact."""
    data = synthetic(1700.0, hz=10.0, filter_hz=50.0)  # omega tau = 0.2: |H| cos(phase) = 0.96
    matched, unmatched = make(force_filter_hz=50.0), make(force_filter_hz=0.0)
    feed(matched, *data)
    feed(unmatched, *data)
    assert matched.k_hat == pytest.approx(1700.0, rel=1e-5)
    assert unmatched.k_hat / 1700.0 - 1.0 < -0.02


@pytest.mark.parametrize('seed', [0, 1, 2])
@pytest.mark.parametrize('k', STIFFNESSES)
def test_converges_with_force_noise(k, seed):
    est = make()
    k_hat = feed(est, *synthetic(k, noise=0.05, seed=seed))
    after = np.arange(k_hat.size) * DT >= 1.0
    assert np.all(np.abs(k_hat[after] - k) <= 0.15 * k), (k_hat[after].min(), k_hat[after].max())
    assert abs(est.k_hat - k) <= 0.05 * k
    assert est.valid
    # the reported standard deviation is honest: the error is within 4 of them
    assert abs(est.k_hat - k) <= 4.0 * est.k_hat_std


def test_valid_needs_twenty_exciting_samples():
    """A perfect fit of a few large steps has a small standard deviation, but (S6) also
    asks for 20 effective samples before k_s may follow."""
    est = make(force_filter_hz=0.0)
    x_n = X0 + 1e-3 * np.arange(30)
    for i, x in enumerate(x_n):
        est.update(300.0 * (x - X0) + 0.2, float(x), DT, True)
        if est.samples_used == 19:
            assert est.k_hat_std <= 0.05 * est.k_hat and not est.valid
    assert est.samples_used == 29 and est.valid
    assert est.k_hat == pytest.approx(300.0, rel=1e-4)


# ---------------------------------------------------------------- bounds and flags
@pytest.mark.parametrize('k, expected, near', [(20.0, 50.0, False), (20000.0, 6000.0, True),
                                              (3000.0, 3000.0, False),
                                              (5000.0, 5000.0, True)])
def test_bounded_to_k_min_k_max_and_near_flag(k, expected, near):
    est = make(k_min=50.0, k_max=6000.0, k_max_margin=0.2)
    k_hat = feed(est, *synthetic(k))
    assert np.all((k_hat >= 50.0) & (k_hat <= 6000.0))
    assert est.k_hat == pytest.approx(expected, rel=1e-5)
    assert est.near_k_max is near  # (S8): k_hat >= 0.8 k_max


def test_a_saturated_estimate_is_not_valid_and_k_s_does_not_follow_it_down():
    """Held at k_min by the projection, k_hat is a bound, not an estimate: not valid, and
    k_s (which falls only to a valid estimate) stays; the excitation test falls back to k_max."""
    est = make(k_min=50.0, force_filter_hz=0.0)
    f_n, x_n = synthetic(20.0, f_lo=0.2, f_hi=1.0, filter_hz=0.0)
    feed(est, f_n, x_n)
    assert est.k_hat == 50.0 and est.saturated and not est.valid
    assert np.all(ks_series(est, 100) == 6000.0)
    feed(est, np.full(3000, f_n[-1]), np.full(3000, x_n[-1]))  # x_bar catches up
    est.update(float(f_n[-1]), float(x_n[-1]) + 1e-5, DT, True)
    assert est.excitation_n == pytest.approx(6000.0 * 1e-5, rel=1e-3)  # k_e = k_max, not 50


def test_forget_data_learns_a_new_surface_and_keeps_k_s():
    """A long loading on one surface outweighs a short one on another for several T_f;
    forget_data (e.g. on a new contact) restarts the regression from the current k_hat."""
    est = make()
    f_n, x_n = synthetic(300.0)
    feed(est, f_n, x_n)
    k_s = ks_series(est, 5000)[-1]
    assert k_s == pytest.approx(300.0, rel=1e-3)
    est.forget_data()
    assert est.k_hat == pytest.approx(300.0, rel=1e-3) and not est.valid
    f_n2, x_n2 = synthetic(800.0)
    feed(est, f_n2, x_n2 + (x_n[-1] - x_n2[0]))
    assert est.k_hat == pytest.approx(800.0, rel=1e-4) and est.valid
    assert est.k_s == k_s  # only k_s_command moves k_s


# ---------------------------------------------------------------- no drift, gating
def converged(k: float = 1700.0, **kw) -> tuple[StiffnessEstimator, float, float]:
    est = make(**kw)
    f_n, x_n = synthetic(k)
    feed(est, f_n, x_n)
    return est, float(f_n[-1]), float(x_n[-1])


def settled(k: float = 1700.0, **kw) -> tuple[StiffnessEstimator, float, float]:
    """Converged, then 1 s at rest so that x_bar of (S5) has caught up with x_n."""
    est, f, x = converged(k, **kw)
    feed(est, np.full(1000, f), np.full(1000, x))
    return est, f, x


def test_no_drift_without_excitation():
    """100 s of constant f and x: nothing moves, bit for bit (no forgetting, (S5))."""
    est, f, x = settled()
    before = (est.k_hat, est.k_hat_std, est.samples_used, est.valid)
    for f_const in (f, f + 0.5):  # consistent with the fit, then not
        k_hat = feed(est, np.full(100_000, f_const), np.full(100_000, x))
        assert np.all(k_hat == before[0])
    assert (est.k_hat, est.k_hat_std, est.samples_used, est.valid) == before


def test_noise_below_the_dead_zone_does_not_move_the_estimate():
    """Steady tracking: f noisy (sigma 0.05 N), x jittering by 0.01 N / k: frozen. With
    the dead zone off (excitation = 0) the same data makes k_hat wander, so the test can fail."""
    rng = np.random.default_rng(3)
    frozen, wandering = settled(1700.0), settled(1700.0, excitation=0.0, time_constant=0.5)
    for est, f, x in (frozen, wandering):
        k0 = est.k_hat
        f_n = f + rng.normal(0.0, 0.05, 20_000)
        x_n = x + rng.normal(0.0, 0.01 / 1700.0, 20_000)
        k_hat = feed(est, f_n, x_n)
        spread = (k_hat.max() - k_hat.min()) / k0
        if est is frozen[0]:
            assert spread == 0.0 and est.k_hat == k0
        else:
            assert spread > 0.2, spread


def test_out_of_contact_samples_are_ignored():
    """Garbage out of contact (huge force, far position) changes nothing: the estimate is
    bit-identical to the run without those samples."""
    f_n, x_n = synthetic(500.0)
    clean, dirty = make(force_filter_hz=0.0), make(force_filter_hz=0.0)
    feed(clean, f_n, x_n)
    for i in range(f_n.size):
        dirty.update(1e3, X0 - 0.1 * (i % 7), DT, False)
        dirty.update(float(f_n[i]), float(x_n[i]), DT, True)
    assert dirty.k_hat == clean.k_hat and dirty.k_hat_std == clean.k_hat_std
    fresh = make()
    feed(fresh, f_n, x_n, contact=False)
    assert fresh.k_hat == 6000.0 and fresh.samples_used == 0 and not fresh.valid


def test_nan_inputs_never_enter_the_estimate():
    f_n, x_n = synthetic(500.0, noise=0.05)
    clean, dirty = make(force_filter_hz=0.0), make(force_filter_hz=0.0)
    feed(clean, f_n, x_n)
    bad = [(math.nan, X0), (X0, math.nan), (math.inf, X0), (1.0, -math.inf)]
    for i in range(f_n.size):
        if i % 10 == 0:
            f_bad, x_bad = bad[(i // 10) % len(bad)]
            assert math.isfinite(dirty.update(f_bad, x_bad, DT, True))
        dirty.update(float(f_n[i]), float(x_n[i]), DT, True)
    assert dirty.k_hat == clean.k_hat
    assert dirty.samples_rejected == f_n.size // 10 and clean.samples_rejected == 0


# ---------------------------------------------------------------- k_s command
def ks_series(est: StiffnessEstimator, steps: int) -> np.ndarray:
    return np.array([est.k_s_command(DT) for _ in range(steps)])


def test_k_s_holds_until_valid_then_follows_rate_limited_and_smooth():
    est = make(k_s_rate_down=1.0, k_s_time_constant=0.1)
    assert np.all(ks_series(est, 500) == 6000.0)  # no data: held at k_hat0
    feed(est, *synthetic(500.0))
    ks = ks_series(est, 4000)
    step = np.diff(np.log(np.r_[6000.0, ks]))
    assert np.all(step <= 0.0)  # monotone, no overshoot
    assert np.all(step >= -1.0 * DT * (1 + 1e-9))  # |d ln k_s/dt| <= rate_down
    assert step[:100].min() == pytest.approx(-1.0 * DT)  # the limit is active at first
    assert np.abs(np.diff(step)).max() <= 1.1e-5  # no steps in the rate after the start
    # ln(6000/500) / rate_down = 2.48 s at the limit, then the 0.1 s lag: within 1 % by 2.9 s
    t_1pct = np.flatnonzero(np.abs(ks / est.k_hat - 1) <= 0.01)[0] * DT
    assert math.log(12.0) < t_1pct < math.log(12.0) + 0.5
    assert ks[-1] == pytest.approx(est.k_hat, rel=1e-6)
    assert est.k_s_log_rate == pytest.approx(0.0, abs=1e-6)


def test_k_s_rises_faster_than_it_falls():
    est = make(k_hat0=500.0, k_s_rate_up=5.0, k_s_rate_down=1.0)
    feed(est, *synthetic(5000.0))
    ks = ks_series(est, 100)
    assert np.diff(np.log(np.r_[500.0, ks])).max() == pytest.approx(5.0 * DT, rel=1e-9)


def test_disabled_holds_k_s_but_still_estimates():
    est = StiffnessEstimator(StiffnessConfig(enabled=False))
    feed(est, *synthetic(500.0))
    assert est.k_hat == pytest.approx(500.0, rel=1e-5) and est.valid
    assert np.all(ks_series(est, 1000) == 6000.0)


def test_reset_restarts_from_the_prior():
    est, _, _ = converged(500.0)
    est.k_s_command(DT)
    est.reset()
    assert (est.k_hat, est.k_s, est.valid, est.samples_used) == (6000.0, 6000.0, False, 0)
    est.reset(k_hat0=1000.0)
    assert est.k_hat == 1000.0 and est.k_s == 1000.0
    feed(est, *synthetic(300.0))
    assert est.k_hat == pytest.approx(300.0, rel=1e-5)


# ---------------------------------------------------------------- rejection
@pytest.mark.parametrize('kw, name', [
    (dict(k_min=0.0), 'k_min'), (dict(k_min=-1.0), 'k_min'),
    (dict(k_min=7000.0), 'k_min < k_max'), (dict(k_hat0=10.0), 'k_hat0'),
    (dict(k_hat0=7000.0), 'k_hat0'), (dict(time_constant=0.0), 'time_constant'),
    (dict(excitation=-0.1), 'excitation'), (dict(valid_tol=0.0), 'valid_tol'),
    (dict(valid_tol=1.5), 'valid_tol'), (dict(k_s_rate_down=0.0), 'k_s_rate_down'),
    (dict(k_s_rate_up=-1.0), 'k_s_rate_up'), (dict(k_max_margin=1.0), 'k_max_margin'),
    (dict(regularisation=0.0), 'regularisation'), (dict(k_max=math.nan), 'k_max'),
    (dict(k_max=math.inf), 'k_max'), (dict(force_floor=0.0), 'force_floor'),
    (dict(force_filter_hz=-1.0), 'force_filter_hz'), (dict(excitation_window='0.2'),
                                                      'excitation_window'),
    (dict(k_s_time_constant=True), 'k_s_time_constant'), (dict(enabled=1), 'enabled'),
])
def test_bad_config_is_rejected_with_a_reason(kw, name):
    with pytest.raises(StiffnessConfigError, match=name) as exc:
        StiffnessConfig(**kw)
    assert isinstance(exc.value, ValueError)


@pytest.mark.parametrize('dt', [0.0, -1e-3, math.nan, math.inf, None])
def test_bad_dt_is_rejected(dt):
    est = make()
    with pytest.raises(StiffnessError, match='dt'):
        est.update(1.0, X0, dt, True)
    with pytest.raises(StiffnessError, match='dt'):
        est.k_s_command(dt)
    assert est.k_hat == 6000.0


@pytest.mark.parametrize('f_n, x_n', [(None, X0), (1.0, 'x'), ([1.0], X0)])
def test_non_numeric_samples_are_rejected(f_n, x_n):
    est = make()
    with pytest.raises(StiffnessError, match='numbers'):
        est.update(f_n, x_n, DT, True)
    assert est.k_hat == 6000.0 and est.samples_used == 0


def test_bad_reset_and_constructor_arguments_are_rejected():
    with pytest.raises(StiffnessConfigError):
        StiffnessEstimator({'k_min': 50.0})
    est = make()
    with pytest.raises(StiffnessError, match='k_hat0'):
        est.reset(k_hat0=1e9)


# ---------------------------------------------------------------- schema
def test_schema_entries_are_complete_and_match_the_config():
    names = [s.name for s in STIFFNESS_SCHEMA]
    assert len(names) == len(set(names))
    assert not set(names) & {s.name for s in CONTROLLER_SCHEMA}  # k_max is shared, not redefined
    for spec in STIFFNESS_SCHEMA:
        assert spec.description.strip() and spec.kind in ('bool', 'double')
        if spec.kind == 'double':
            assert isinstance(spec.default, float) and spec.lo <= spec.default <= spec.hi
    cfg = stiffness_config_from_values({}, k_max=6000.0, k_s=6000.0, force_filter_hz=200.0)
    assert cfg == StiffnessConfig()  # the dataclass defaults are the schema defaults
    cfg = stiffness_config_from_values({'stiffness_estimation': True, 'k_min': 100.0},
                                       k_max=5000.0, k_s=4000.0, force_filter_hz=0.0)
    assert (cfg.enabled, cfg.k_min, cfg.k_max, cfg.k_hat0) == (True, 100.0, 5000.0, 4000.0)


@pytest.mark.parametrize('values, match', [({'stiffness_bogus': 1.0}, 'unknown'),
                                           ({'stiffness_valid_tol': 2.0}, 'stiffness_valid_tol'),
                                           ({'stiffness_estimation': 'yes'}, 'enabled'),
                                           ({'k_min': 6000.0}, 'k_min')])
def test_schema_values_are_validated(values, match):
    with pytest.raises(StiffnessConfigError, match=match):
        stiffness_config_from_values(values, k_max=6000.0, k_s=6000.0, force_filter_hz=200.0)


def test_update_allocates_nothing_that_stays():
    est = make()
    f_n, x_n = synthetic(500.0, duration=1.0)
    feed(est, f_n[:100], x_n[:100])
    samples = list(zip(f_n[100:].tolist(), x_n[100:].tolist()))
    tracemalloc.start()
    for i, (f, x) in enumerate(samples):
        if i == 10:  # every attribute has been rebound once: the baseline
            base = tracemalloc.take_snapshot()
        est.update(f, x, DT, True)
        est.k_s_command(DT)
    grown = sum(s.size_diff for s in tracemalloc.take_snapshot().compare_to(base, 'filename')
                if 'stiffness' in s.traceback[0].filename)
    tracemalloc.stop()
    assert est.samples_used > 100 and grown < 512, grown


# ---------------------------------------------------------------- open-loop study
# The estimator fed, after the fact, with the logs of the existing closed loop (paper
# scenario, 2 periods of delay, masses 50 % off), which does not use it. 8 s per run.
from stiffness_study import estimate_open_loop, open_loop_case  # noqa: E402

from hybrid_force_controller.core.scenario import ScenarioConfig, run_scenario  # noqa: E402

STUDY_S = 8.0


@pytest.fixture(scope='module')
def study() -> dict:
    cases = {}
    for k in STIFFNESSES:
        for scale in (0.5, 1.5):
            cases[k, scale, 0.0] = open_loop_case(k, scale, 0.0, duration=STUDY_S)
        cases[k, 0.5, 0.05] = open_loop_case(k, 0.5, 0.05, duration=STUDY_S)
    return cases


@pytest.mark.parametrize('scale', [0.5, 1.5])
@pytest.mark.parametrize('k', STIFFNESSES)
def test_open_loop_estimate_within_10_percent_within_2_s(study, k, scale):
    r = study[k, scale, 0.0]
    assert r['t_10pct'] <= 2.0, r['t_10pct']  # the phase-2 target; measured <= 0.1 s
    assert r['t_valid'] <= 0.5  # valid (k_s may follow) well within the target
    assert abs(r['final_err']) <= 0.01


@pytest.mark.parametrize('k', STIFFNESSES)
def test_open_loop_estimate_with_force_noise_stays_within_15_percent(study, k):
    r = study[k, 0.5, 0.05]
    tr = r['trace']
    after = tr.t >= tr.t_contact + 2.0
    err = np.abs(tr.k_hat[after] - k) / k
    assert err.max() <= 0.15, err.max()  # measured <= 1.1 %
    assert r['t_10pct'] <= 2.0
    assert tr.valid[after].all()


@pytest.mark.parametrize('noise', [0.0, 0.05])
@pytest.mark.parametrize('k', STIFFNESSES)
def test_the_loading_excites_and_steady_tracking_does_not(study, k, noise):
    """All information comes from the initial loading (and its overshoot, masses 50 %
    off); over t >= 5 s the motion along n stays inside the dead zone (S5), so k_hat is
    frozen: the force loop must excite the estimator (contact, f_d steps)."""
    tr = study[k, 0.5, noise]['trace']
    used = tr.t[tr.excited]
    assert used.size > 100 and used.max() < 5.0
    steady = tr.t >= 5.0
    assert np.ptp(tr.k_hat[steady]) == 0.0
    assert tr.excitation_n[steady].max() < 0.05  # below delta_f, with a margin >= 1.6


def test_steady_tracking_alone_never_validates_the_estimate():
    """Fed only the steady part (t >= 5 s) of a run, the estimator sees too little
    excitation to become valid (a few noise-level samples pass the k_max-scaled dead zone
    and move k_hat, measured 690 N/m for 500), so k_s would not move."""
    res = run_scenario(ScenarioConfig(k=500.0, theta_hat0_scale=0.5, delay_steps=2,
                                      noise_sigma=0.05, duration=STUDY_S))
    steady = res.t >= 5.0
    sliced = dataclasses.replace(res, t=res.t[steady], x_W=res.x_W[steady],
                                 f_W=res.f_W[steady], in_contact=res.in_contact[steady])
    tr = estimate_open_loop(sliced)
    assert not tr.valid.any() and np.all(tr.k_s == 6000.0)
    assert abs(tr.k_hat[-1] / 500.0 - 1.0) > 0.15  # and it would be a poor estimate


def test_without_the_dead_zone_noise_makes_the_estimate_wander(study):
    """Negative control on the same logs: with delta_f = 0 (every in-contact sample used
    and forgotten, T_f = 0.5 s) the noisy steady tracking drags k_hat by more than 15 %."""
    res = run_scenario(ScenarioConfig(k=300.0, theta_hat0_scale=0.5, delay_steps=2,
                                      noise_sigma=0.05, duration=STUDY_S))
    from stiffness_study import CONFIG
    tr = estimate_open_loop(res, dataclasses.replace(CONFIG, excitation=0.0, time_constant=0.5))
    steady = tr.t >= 5.0
    assert np.abs(tr.k_hat[steady] / 300.0 - 1.0).max() > 0.15


# ---------------------------------------------------------------- phase-2 prototype
# k_s (and lambda2, Gamma) set from k_hat each tick by a subclass of the control law in
# test/stiffness_prototype.py; the targets of issue 13. 12 s runs, 2 periods of delay.
from stiffness_prototype import closed_loop_case, step_case  # noqa: E402

LOOP_S = 12.0


@pytest.mark.parametrize('scale', [0.5, 1.5])
@pytest.mark.parametrize('k', STIFFNESSES)
def test_closed_loop_with_the_estimate_meets_the_targets(k, scale):
    r = closed_loop_case(k, scale, duration=LOOP_S)
    m = r['metrics']
    assert r['t_10pct'] <= 2.0, r['t_10pct']  # measured <= 0.09 s
    assert r['t_k_s_10pct'] <= 1.0  # k_s (rate-limited, 10/s) follows: measured <= 0.54 s
    assert m['rms_force_error_n'] <= 0.02 and m['rms_position_error_m'] <= 2e-4, m
    assert m['contact_lost_s'] == 0.0
    np.testing.assert_allclose(m['theta_hat_final'], r['res'].theta_true, rtol=0.05)


@pytest.mark.parametrize('k', STIFFNESSES)
def test_closed_loop_with_force_noise_keeps_the_estimate_within_15_percent(k):
    r = closed_loop_case(k, 0.5, noise=0.05, duration=LOOP_S)
    m = r['metrics']
    assert r['max_err_late'] <= 0.15, r['max_err_late']  # measured <= 1.2 %
    assert m['rms_force_error_n'] <= 0.02 and m['rms_position_error_m'] <= 2e-4, m
    assert m['contact_lost_s'] == 0.0


@pytest.fixture(scope='module')
def steps() -> dict:
    return {(k, mode): step_case(k, mode) for k in (500.0, 5000.0)
            for mode in ('off', 'k_s', 'bandwidth')}


def test_force_step_settles_alike_at_500_and_5000_with_the_estimate(steps):
    """f_d 1 -> 2 N: with k_s, lambda2 and Gamma from k_hat the 2 % settling time at
    k = 500 is within 30 % of the one at 5000 (measured 0.22 s vs 0.19 s)."""
    soft, stiff = steps[500.0, 'bandwidth'], steps[5000.0, 'bandwidth']
    assert 0.7 <= soft['t_settle'] / stiff['t_settle'] <= 1.3, (soft['t_settle'],
                                                               stiff['t_settle'])
    assert not soft['contact_lost'] and not stiff['contact_lost']


def test_force_step_is_much_slower_at_500_without_the_estimate(steps):
    """The current controller (k_s = 6000 fixed): damping 0.24 at k = 500, settling 10x
    slower (measured 2.34 s vs 0.22 s); at 5000 it is as fast (0.21 s)."""
    off, on = steps[500.0, 'off'], steps[500.0, 'bandwidth']
    assert off['t_settle'] > 5.0 * on['t_settle']
    assert steps[5000.0, 'off']['t_settle'] <= 1.3 * steps[5000.0, 'bandwidth']['t_settle']


def test_k_s_alone_does_not_equalise_the_step(steps):
    """k_s := k_hat without rescaling lambda2: the normal loop at k = k_s is
    s^2 + lambda1 s + lambda2 k, overdamped at 500 (slow pole 1.3 rad/s): the step at 500
    takes more than 1.3x the one at 5000 (measured 0.47 s vs 0.22 s), so lambda2 must scale."""
    assert steps[500.0, 'k_s']['t_settle'] > 1.3 * steps[5000.0, 'k_s']['t_settle']


def test_a_fivefold_underestimate_breaks_the_loop():
    """Why k_s falls only to a valid estimate: with k_s = k/5 (gains of mode bandwidth)
    the normal loop's fast pole (k/k_s) lambda1 = 200 rad/s meets the delayed velocity
    loop and the force oscillates (contact lost); k_s = k/3 still holds."""
    bad = closed_loop_case(5000.0, 0.5, duration=8.0, k_s_fixed=1000.0)['metrics']
    ok = closed_loop_case(500.0, 0.5, duration=8.0, k_s_fixed=500.0 / 3.0)['metrics']
    assert bad['contact_lost_s'] > 0.1 and bad['rms_force_error_n'] > 0.1, bad
    assert ok['rms_force_error_n'] <= 0.02 and ok['contact_lost_s'] == 0.0, ok
