"""
Issue 13 targets.

The controller learns the surface in the closed loop (paper scenario through the loop engine,
masses 50 % off via theta_hat0_scale 0.5 / 1.5, 2 periods of delay unless the real-time timing
model is used). Fixed seeds; 8-13 s runs.

    k in {300, 500, 1700, 5000} N/m: |k_hat - k| <= 10 % k within 2 s of the first contact
    (3 s under TimingModel.ros_measured), force error <= 0.02 N RMS and position error
    <= 0.2 mm RMS over t >= 5 s, no contact loss over t >= 5 s; with force noise
    sigma = 0.05 N k_hat stays within 15 %; the f_d step 1 -> 2 N settles in the same
    time (+-30 %) at 500 and 5000 N/m.
"""
from __future__ import annotations

import dataclasses
import math

from helpers.offline import stiffness_metrics as metrics, stiffness_run as run, STIFFNESSES
from helpers.pins import check_pinned, numbers
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.engine import Event
from hybrid_force_controller.core.offline.scenario import ScenarioResult
from hybrid_force_controller.core.offline.timing import TimingModel
import numpy as np
import pytest


SCALES = (0.5, 1.5)


def t_contact(res: ScenarioResult) -> float:
    """Time of the first sample with the true force in contact."""
    return float(res.t[np.argmax(res.in_contact)])


def time_within(res: ScenarioResult, tol: float) -> float:
    """
    Time from the first contact until k_hat enters k (1 +- tol) for good.

    An unknown (NaN) estimate counts as outside; inf: never.
    """
    outside = np.flatnonzero(~(np.abs(res.k_hat - res.k_true) <= tol * res.k_true))
    if outside.size == 0:
        return 0.0
    if outside[-1] + 1 >= res.t.size:
        return math.inf
    return float(res.t[outside[-1] + 1]) - t_contact(res)


# ---------------------------------------------------------------- targets
@pytest.mark.parametrize('scale', SCALES)
@pytest.mark.parametrize('k', STIFFNESSES)
def test_the_estimate_converges_and_the_loop_meets_the_targets(model, k, scale):
    res = run(model, k, scale)
    m = metrics(res)
    assert time_within(res, 0.10) <= 2.0  # measured 0.02-0.03 s
    assert m['rms_force_error_n'] <= 0.02 and m['rms_position_error_m'] <= 2e-4, m
    assert m['contact_lost_window_s'] == 0.0
    assert m['contact_lost_s'] <= 0.15  # the start-up transient may lift off briefly
    st = res.runtime.stiffness_status()
    assert st.enabled and st.valid and st.k_s == pytest.approx(k, rel=0.02)
    assert st.lambda2 == pytest.approx(0.1 * 6000.0 / st.k_s)
    assert m['stiffness_estimate_n_per_m'] == pytest.approx(k, rel=0.01)
    if scale == 0.5:  # the pinned run (test_pinned_figures.py's docstring)
        check_pinned(f'stiffness_k{k:.0f}_theta0.5', numbers(m))
    np.testing.assert_allclose(m['theta_hat_final'], res.theta_true, rtol=0.05)


@pytest.mark.parametrize('k', STIFFNESSES)
def test_with_force_noise_the_estimate_stays_within_15_percent(model, k):
    res = run(model, k, 0.5, noise_sigma=0.05, seed=7)
    late = res.t >= t_contact(res) + 2.0
    err = np.abs(res.k_hat[late] - k) / k
    assert np.all(err <= 0.15), np.nanmax(err)  # NaN (unknown) fails too; measured <= 6 %
    m = metrics(res)
    assert m['rms_force_error_n'] <= 0.02 and m['contact_lost_window_s'] == 0.0, m


@pytest.mark.parametrize('scale', SCALES)
@pytest.mark.parametrize('k', STIFFNESSES)
def test_under_the_real_time_timing_model_the_estimate_converges(model, k, scale):
    """
    Latency, jitter, stalls of 1-30 ms (TimingModel.ros_measured).

    The state's dt varies and some states are late; within 10 % within 3 s all the same.
    """
    res = run(model, k, scale, duration=8.0, delay_steps=0,
              timing=TimingModel.ros_measured(seed=int(k) + int(10 * scale)))
    assert time_within(res, 0.10) <= 3.0
    assert metrics(res)['contact_lost_window_s'] == 0.0


def test_steady_tracking_does_not_move_the_estimate(model):
    """
    After the loading the motion along n stays inside the dead zone (S5).

    Over t >= 5 s k_hat is frozen even with force noise (no drift, no forgetting).
    """
    res = run(model, 1700.0, 0.5, duration=10.0, noise_sigma=0.05, seed=3)
    steady = res.k_hat[res.t >= 5.0]
    assert np.all(np.isfinite(steady)) and np.ptp(steady) == 0.0


@pytest.mark.parametrize('k0, k1', [(1700.0, 3000.0), (3000.0, 1700.0), (5000.0, 300.0),
                                    (300.0, 5000.0)])
def test_a_surface_that_changes_under_the_tool_is_learned_again(model, k0, k1):
    """
    Learn k again when it changes in contact at t = 6 s (the sim's surface swapped, x0 kept).

    The misfit is detected (S9), k_s returns to 6000 and falls to the new estimate; without (S9)
    the old and new data gave a 'valid' 889 N/m for 3000 N/m. 300 -> 5000 N/m throws the tool off
    with or without the estimate (measured 0.22 s and 0.14 s lost).
    """
    def swap(rt, plant):
        plant.surface = dataclasses.replace(plant.surface, k=k1)
    res = run(model, k0, 0.5, duration=10.0, events=[Event(6.0, swap)])
    after = res.t >= 6.0
    outside = np.flatnonzero(~(np.abs(res.k_hat[after] - k1) <= 0.1 * k1))
    assert outside[-1] + 1 < after.sum() and res.t[after][outside[-1] + 1] - 6.0 <= 2.0
    st = res.runtime.stiffness_status()
    assert st.changes >= 1 and st.valid and st.k_s == pytest.approx(k1, rel=0.02)
    lost = float(np.sum(~res.in_contact[after])) * 1e-3
    assert lost <= (0.3 if k1 > 2.0 * k0 else 0.0), lost


def test_without_the_change_test_old_and_new_data_give_a_wrong_valid_estimate(model):
    """
    Negative control of (S9).

    1700 -> 3000 N/m with stiffness_change_force = 0 ends with a 'valid' estimate of 955 N/m (k/k_s
    = 3.1, near where the loop breaks).
    """
    def swap(rt, plant):
        plant.surface = dataclasses.replace(plant.surface, k=3000.0)
    res = run(model, 1700.0, 0.5, duration=10.0, events=[Event(6.0, swap)],
              overrides={'stiffness_change_force': 0.0})
    st = res.runtime.stiffness_status()
    assert st.valid and st.changes == 0 and st.k_hat < 0.5 * 3000.0, st


def test_a_parameter_set_keeps_the_estimate_in_the_loop(model):
    """
    runtime.set_params (f_d, an estimator rate) at t = 3 s.

    The estimate, its validity and the k_s in use are the same right after; a new prior makes it
    unknown.
    """
    seen = []

    def set_(values):
        def action(rt, plant):
            before = rt.stiffness_status()
            rt.set_params(rt.validate({'theta_hat0': list(rt.params.law.theta_hat0), **values}))
            seen.append((before, rt.stiffness_status()))
        return action
    run(model, 500.0, 0.5, duration=4.0, events=[
        Event(3.0, set_({'f_d': 1.2, 'stiffness_k_s_rate_up': 5.0})),
        Event(3.5, set_({'f_d': 1.2, 'stiffness_k_hat0': 2000.0}))])
    (before, after), (_, reset) = seen
    assert before.valid and before.k_hat == pytest.approx(500.0, rel=1e-3)
    assert after == before
    assert math.isnan(reset.k_hat) and not reset.valid
    assert reset.k_s == pytest.approx(before.k_s, rel=1e-3)  # k_s kept, moves rate-limited


# ---------------------------------------------------------------- force step
def step_run(model, k, extra=None, duration=13.0) -> float:
    """
    Return the 2 % settling time of the true force after f_d 1 -> 2 N at t = 10 s.

    f_d is set through an Event (a parameter set) as a step (``f_d_rate`` 0: the step response
    is what is compared); masses 50 % low, 2 periods of delay.
    """
    theta0 = (model.theta_nominal * 0.5).tolist()
    values = {'theta_hat0': theta0, 'f_d_rate': 0.0, **(extra or {})}
    set_f_d = Event(10.0, lambda rt, plant: rt.set_params(rt.validate({**values, 'f_d': 2.0})))
    res = run(model, k, 0.5, duration=duration, overrides=values, events=[set_f_d])
    f_n = res.f_true_W @ res.n_W
    after = res.t >= 10.0
    assert not (~res.in_contact[after]).any()
    outside = np.flatnonzero(np.abs(f_n[after] - 2.0) > 0.02)
    assert outside.size and outside[-1] + 1 < after.sum(), 'did not settle'
    return float(res.t[after][outside[-1] + 1] - 10.0)


@pytest.fixture(scope='module')
def steps(model) -> dict:
    return {'on 500': step_run(model, 500.0), 'on 5000': step_run(model, 5000.0),
            'off 500': step_run(model, 500.0, {'stiffness_estimation': False}, 20.0),
            'off 5000': step_run(model, 5000.0, {'stiffness_estimation': False}),
            'k_s alone 500': step_run(model, 500.0, {'stiffness_estimation': False,
                                                     'k_s': 500.0, 'min_delay_margin': 0.0})}


def test_force_step_settles_alike_at_500_and_5000_with_the_estimate(steps):
    """Measured 0.447 s at 500 N/m and 0.474 s at 5000 N/m."""
    assert 0.7 <= steps['on 500'] / steps['on 5000'] <= 1.3, steps


def test_force_step_is_much_slower_at_500_without_the_estimate(steps):
    """
    k_s = 6000 fixed.

    Damping 0.24 at 500 N/m, measured 4.38 s (10x); at 5000 N/m the fixed controller is as fast
    (0.450 s).
    """
    assert steps['off 500'] > 5.0 * steps['on 500'], steps
    assert steps['off 5000'] <= 1.3 * steps['on 5000'], steps


def test_k_s_alone_without_the_lambda2_rescale_does_not_equalise_the_step(steps):
    """
    k_s = k = 500 with lambda2 = 0.1 (the literal k_s := k_hat).

    The normal loop is s^2 + lambda1 s + lambda2 k, overdamped (slow pole 1.3 rad/s), measured
    0.641 s, more than the +-30 % band around the 5000 N/m step: lambda2 must scale with 1/k_s.
    """
    assert steps['k_s alone 500'] > 1.3 * steps['on 5000'], steps


# ------------------------------------------------- why k_s falls only to a valid estimate
def fixed_k_s_run(model, k, k_s) -> dict:
    """
    Run with the estimate off and the law's k_s forced to k_s from t = 0.

    ``set_k_s``, as the estimate would set it: lambda2 = lambda2_0 k_s0 / k_s.
    """
    force = Event(0.0, lambda rt, plant: rt.ctrl.set_k_s(k_s))
    res = run(model, k, 0.5, duration=8.0, events=[force],
              overrides={'stiffness_estimation': False})
    assert res.runtime.ctrl.k_s == k_s
    return metrics(res)


def test_a_fivefold_underestimate_breaks_the_loop_and_threefold_holds(model):
    """
    Check that k_s = k/5 breaks the loop and k_s = k/3 holds.

    At k_s = k/5 the normal loop's fast pole (k/k_s) lambda1 = 200 rad/s meets the delayed
    velocity loop; the force oscillates (measured 0.145 N RMS over t >= 5 s, 7x the target).
    """
    bad = fixed_k_s_run(model, 5000.0, 1000.0)
    ok = fixed_k_s_run(model, 500.0, 500.0 / 3.0)
    assert bad['rms_force_error_n'] > 0.1, bad
    assert ok['rms_force_error_n'] <= 0.02 and ok['contact_lost_window_s'] == 0.0, ok


# ---------------------------------------------------------------- the figures of docs/design.md
def _print_figures() -> None:
    """``PYTHONPATH=. .venv/bin/python test/test_stiffness_closed_loop.py``: the tables."""
    model = RobotModel.from_urdf()
    print('k N/m  masses  estimate  t_10% s  k_hat err  rms f_n N  rms pos mm  lost s  '
          'lost t>=5 s')
    for k in STIFFNESSES:
        for scale in SCALES:
            for on in (True, False):
                res = run(model, k, scale, overrides={'stiffness_estimation': on})
                m = metrics(res)
                print(f'{k:5.0f}  {scale:6.1f}  {"on" if on else "off":8s}  '
                      f'{time_within(res, 0.1):7.3f}  {res.k_hat[-1] / k - 1:+9.2%}  '
                      f"{m['rms_force_error_n']:9.4f}  {1e3 * m['rms_position_error_m']:10.4f}"
                      f"  {m['contact_lost_s']:6.3f}  {m['contact_lost_window_s']:11.3f}")
    for k in STIFFNESSES:
        res = run(model, k, 0.5, noise_sigma=0.05, seed=7)
        late = res.t >= t_contact(res) + 2.0
        print(f'noise 0.05 N, k {k:5.0f}: max |k_hat - k|/k after 2 s '
              f'{np.nanmax(np.abs(res.k_hat[late] - k)) / k:.2%}, '
              f"rms f_n {metrics(res)['rms_force_error_n']:.4f} N")
    for k in STIFFNESSES:
        for scale in SCALES:
            res = run(model, k, scale, duration=8.0, delay_steps=0,
                      timing=TimingModel.ros_measured(seed=int(k) + int(10 * scale)))
            print(f'ros_measured timing, k {k:5.0f}, masses {scale}: t_10% '
                  f'{time_within(res, 0.1):.3f} s')
    print('f_d step 1 -> 2 N, 2 % settling, s:', {
        name: round(value, 3) for name, value in steps.__wrapped__(model).items()})
    for k, k_s in ((5000.0, 1000.0), (5000.0, 5000.0 / 3.0), (500.0, 500.0 / 3.0)):
        print(f'k {k:5.0f}, k_s = k/{k / k_s:.0f}: rms f_n '
              f"{fixed_k_s_run(model, k, k_s)['rms_force_error_n']:.4f} N")


if __name__ == '__main__':
    _print_figures()
