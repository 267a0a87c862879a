"""
Online stiffness estimate (core/law/stiffness.py): the commanded k_s, bad settings, settings.

Unit tests on synthetic data (fixed seeds): k_s follows k_hat rate-limited and smooth, bad
configurations, time steps and samples are refused with the reason, and a reconfiguration keeps
what was learnt. The estimate itself: test_stiffness.py.
"""
from __future__ import annotations

import math
import tracemalloc

from helpers.offline import (DT, feed_estimator as feed, k_s_series as ks_series,
                             stiffness_estimator as make, synthetic_press as synthetic, X0)
from hybrid_force_controller.core.law.stiffness import (StiffnessConfig, StiffnessConfigError,
                                                        StiffnessError, StiffnessEstimator)
import numpy as np
import pytest


# ---------------------------------------------------------------- k_s command
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
    est = make()
    feed(est, *synthetic(500.0))
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
