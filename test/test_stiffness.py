"""
Online stiffness estimate (core/law/stiffness.py): unit tests on synthetic data.

Fixed seeds.

The estimate in the closed loop (runtime, law, parameters, margin, targets) is tested in
test_stiffness_loop.py, the recording and report in test_stiffness_tools.py.
"""
from __future__ import annotations

import math
import tracemalloc

from hybrid_force_controller.core.law.stiffness import (StiffnessConfig, StiffnessConfigError,
                                                        StiffnessError, StiffnessEstimator)
from hybrid_force_controller.core.runtime.filters import LowPassFilter
import numpy as np
import pytest


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
    return StiffnessEstimator(StiffnessConfig(**{'enabled': True, **kw}))


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
    """
    Check (S0): a filter on the force but not on x_n biases k_hat; the matching one is exact.

    Feeding a 50 Hz-filtered force with the filter switched off in the estimator (x_n
    unfiltered) biases k_hat; with the matching filter it is exact.
    """
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
    """
    A perfect fit of a few large steps has a small standard deviation.

    But (S6) also asks for 20 effective samples before k_s may follow.
    """
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
    """
    Held at k_min by the projection, k_hat is a bound, not an estimate.

    Not valid, and k_s (which falls only to a valid estimate) stays; the excitation test falls back
    to k_max.
    """
    est = make(k_min=50.0, force_filter_hz=0.0)
    f_n, x_n = synthetic(20.0, f_lo=0.2, f_hi=1.0, filter_hz=0.0)
    feed(est, f_n, x_n)
    assert est.k_hat == 50.0 and est.saturated and not est.valid
    assert np.all(ks_series(est, 100) == 6000.0)
    feed(est, np.full(3000, f_n[-1]), np.full(3000, x_n[-1]))  # x_bar catches up
    est.update(float(f_n[-1]), float(x_n[-1]) + 1e-5, DT, True)
    assert est.excitation_n == pytest.approx(6000.0 * 1e-5, rel=1e-3)  # k_e = k_max, not 50


def test_forget_data_learns_a_new_surface_and_keeps_k_s():
    """
    A long loading on one surface outweighs a short one on another for several T_f.

    Forget_data (e.g. on a new contact) restarts the regression from the current k_hat.
    """
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


def test_re_anchor_forgets_the_origin_of_x_n_and_keeps_what_was_learnt_of_k():
    """
    A moving normal (surface.py): x_n jumped while the fit was paused; re_anchor moves its origin.

    Without it the jump is a misfit, a change of the surface (S9): k_hat unknown again. With it
    k_hat, its validity and most of its information stay, and the next loading goes on fitting k.
    """
    est, f, x = settled(1700.0)
    std = est.k_hat_std
    jumped = x + 0.02  # x_n's origin moved 2 cm (n_hat turned while the tool slid)
    plain, _, _ = settled(1700.0)
    feed(plain, np.full(50, f), np.full(50, jumped))
    assert plain.changes == 1  # the check can fail: a jump unannounced is a new surface
    est.re_anchor()
    assert est.k_hat == pytest.approx(1700.0, rel=1e-4) and est.valid
    assert est.k_hat_std < 10.0 * std  # kappa's information kept (marginal over b)
    f_n, x_n = synthetic(1700.0)
    feed(est, f_n, x_n - x_n[0] + jumped)
    assert est.changes == 0 and est.restarts == 0
    assert est.k_hat == pytest.approx(1700.0, rel=1e-4) and est.valid


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
    """
    100 s of constant f and x.

    Nothing moves, bit for bit (no forgetting, (S5)); with the change test (S9) off, not even when
    the force no longer fits.
    """
    est, f, x = settled(change_force=0.0)
    before = (est.k_hat, est.k_hat_std, est.samples_used, est.valid)
    for f_const in (f, f + 0.5):  # consistent with the fit, then not
        k_hat = feed(est, np.full(100_000, f_const), np.full(100_000, x))
        assert np.all(k_hat == before[0])
    assert (est.k_hat, est.k_hat_std, est.samples_used, est.valid) == before


@pytest.mark.parametrize('jump, detect_ms', [(0.5, 14), (5.0, 1), (-0.5, 14)])
def test_a_lasting_misfit_is_a_change_of_the_surface(jump, detect_ms):
    """
    Check (S9): a force that leaves the fitted line at constant x is a changed surface.

    k or x0 changed under the tool: detected once (|eps| - 0.2 N) dt sums to 0.2 N x 20 ms;
    the fit restarts from the prior and the k_s command jumps up to k_s0; noise (sigma 0.05 N,
    filtered) on 100 s of a consistent force never triggers it.
    """
    est, f, x = settled(1700.0)
    ks_series(est, 5000)
    rng = np.random.default_rng(5)
    filt = LowPassFilter(200.0, size=1)
    noisy = [filt.update(np.array([v]), DT) and float(filt.value[0])
             for v in f + rng.normal(0.0, 0.05, 100_000)]
    feed(est, noisy, np.full(len(noisy), x))
    assert est.changes == 0 and est.valid and est.k_s == pytest.approx(1700.0, rel=1e-3)
    for i in range(100):
        est.update(f + jump, x, DT, True)
        if est.changes:
            break
    assert i + 1 == detect_ms and est.changes == est.restarts == 1
    assert est.k_hat == 6000.0 and not est.valid and est.k_s == 6000.0


def test_noise_below_the_dead_zone_does_not_move_the_estimate():
    """
    Steady tracking: f noisy (sigma 0.05 N), x jittering by 0.01 N / k: frozen.

    With the dead zone off (excitation = 0) the same data makes k_hat wander, so the test can fail.
    """
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
    """
    Garbage out of contact (huge force, far position) changes nothing.

    The estimate is bit-identical to the run without those samples.
    """
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
    est = make(enabled=False)
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
    ({'k_min': 0.0}, 'k_min'), ({'k_min': -1.0}, 'k_min'),
    ({'k_min': 7000.0}, 'k_min < k_max'), ({'k_hat0': 10.0}, 'k_hat0'),
    ({'k_hat0': 7000.0}, 'k_hat0'), ({'time_constant': 0.0}, 'time_constant'),
    ({'excitation': -0.1}, 'excitation'), ({'valid_tol': 0.0}, 'valid_tol'),
    ({'valid_tol': 1.5}, 'valid_tol'), ({'k_s_rate_down': 0.0}, 'k_s_rate_down'),
    ({'k_s_rate_up': -1.0}, 'k_s_rate_up'), ({'k_max_margin': 1.0}, 'k_max_margin'),
    ({'regularisation': 0.0}, 'regularisation'), ({'k_max': math.nan}, 'k_max'),
    ({'k_max': math.inf}, 'k_max'), ({'force_floor': 0.0}, 'force_floor'),
    ({'force_filter_hz': -1.0}, 'force_filter_hz'),
    ({'excitation_window': '0.2'}, 'excitation_window'),
    ({'k_s_time_constant': True}, 'k_s_time_constant'), ({'enabled': 1}, 'enabled'),
    ({'k_s0': 0.0}, 'k_s0'), ({'k_hat0': -1.0}, 'k_hat0'),
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


# ---------------------------------------------------------------- settings
def test_prior_is_k_hat0_or_the_configured_k_s_clipped():
    assert StiffnessConfig().prior == 6000.0  # k_hat0 = 0: k_s0
    assert StiffnessConfig(k_hat0=800.0).prior == 800.0
    assert StiffnessConfig(k_s0=9000.0).prior == 6000.0  # k_s0 above k_max: clipped
    assert StiffnessConfig(k_s0=20.0).prior == 50.0


def test_reconfigure_keeps_the_estimate_unless_prior_or_bounds_change():
    """
    Settings that only act on later samples keep the data.

    The estimate continues exactly as one never reconfigured; a new prior restarts from it, new
    bounds from the clipped k_hat; the k_s command is kept in every case.
    """
    f_n, x_n = synthetic(500.0)
    a, b = make(), make()
    feed(a, f_n[:1500], x_n[:1500])
    feed(b, f_n[:1500], x_n[:1500])
    k_s = ks_series(a, 200)[-1]
    ks_series(b, 200)
    b.reconfigure(StiffnessConfig(k_s_rate_up=5.0, k_max_margin=0.3, valid_tol=0.05))
    feed(a, f_n[1500:], x_n[1500:])
    feed(b, f_n[1500:], x_n[1500:])
    assert b.k_hat == a.k_hat and b.k_hat_std == a.k_hat_std and b.valid
    b.reconfigure(StiffnessConfig(k_min=700.0))
    assert b.k_hat == 700.0 and not b.valid and b.samples_used == a.samples_used
    b.reconfigure(StiffnessConfig(k_min=700.0, k_hat0=3000.0))
    assert b.k_hat == 3000.0 and not b.valid and b.k_s == k_s
    with pytest.raises(StiffnessConfigError):
        b.reconfigure({'k_min': 1.0})


def test_k_s_command_restarts_from_a_given_value_and_moves_into_new_bounds():
    est = make()
    est.set_k_s_command(8000.0)  # e.g. the law's k_s above k_max when switched on
    ks = ks_series(est, 2000)
    assert ks[0] < 8000.0 and ks[-1] == pytest.approx(6000.0, rel=1e-6)
    assert np.all(np.diff(np.log(np.r_[8000.0, ks])) >= -10.0 * DT * (1 + 1e-9))
    for bad in (0.0, -1.0, math.nan, math.inf, '1'):
        with pytest.raises(StiffnessError, match='k_s'):
            est.set_k_s_command(bad)


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
