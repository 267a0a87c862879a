"""
The stiffness estimate in the core.

The law's O(1) set_k_s, the parameter group, eq. (29) at the estimate, the delay margin over the
k_s range, and StiffnessLoop (what the runtime runs on every new state). Synthetic data and short
loops; the closed-loop targets of issue 13 are in test_stiffness_closed_loop.py. Fixed seeds.
"""
from __future__ import annotations

import dataclasses
import math
import tracemalloc

from helpers.offline import DT, synthetic_press as synthetic
from hybrid_force_controller.core.config.params import (build_params, CONTROLLER_SCHEMA,
                                                        ParameterValidationError, STIFFNESS_FIELDS)
from hybrid_force_controller.core.law.control_law import ControlError, HybridForceController
from hybrid_force_controller.core.law.margin import (axis_margin, delay_margin,
                                                     estimate_operating_points, K_S_GRID)
from hybrid_force_controller.core.law.reference import SineReference
from hybrid_force_controller.core.law.stiffness import StiffnessConfig
from hybrid_force_controller.core.law.stiffness_loop import StiffnessLoop
from hybrid_force_controller.core.offline.scenario import PAPER_Q0
from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime
import numpy as np
import pytest


Q0 = np.array(PAPER_Q0)
QDOT = np.array([0.1, -0.2])
N_W = np.array([0.0, -1.0, 0.0])


def law(model, **values):
    return build_params(model, values).law


def r_normal(ctrl: HybridForceController, f_n: float) -> tuple[float, float]:
    """Return the normal parts of r and rdot at the paper pose for a normal force f_n (N)."""
    kin = ctrl.model.kinematics(Q0, QDOT)
    ref = SineReference(np.array([1.0, 1.6, 0.0]), np.array([0.1, 0.0, 0.0]), 1.0)(0.3)
    r, rdot = ctrl.reference_velocity(kin, ref, (f_n * N_W)[ctrl.model.task_index])[:2]
    n = N_W[list(ctrl.model.task_axes)]
    return float(n @ r), float(n @ rdot)


# ---------------------------------------------------------------- the law
def test_set_k_s_is_the_law_of_a_gain_set_with_k_s_and_lambda2_rescaled(model):
    """
    set_k_s(500) gives the same effort and integration as building the gains with k_s = 500.

    lambda2 = 0.1 * 6000/500 and the anti-windup bound scaled alike.
    """
    fast = HybridForceController(model, law(model))
    full = HybridForceController(model, dataclasses.replace(
        law(model), k_s=500.0, lambda2=1.2, integral_limit=2.0 * 500.0 / 6000.0))
    fast.set_k_s(500.0)
    assert (fast.k_s, fast.lambda2) == (500.0, pytest.approx(1.2, rel=1e-15))
    ref = SineReference(np.array([1.0, 1.6, 0.0]), np.array([0.1, 0.0, 0.0]), 1.0)
    for i, f_n in enumerate((1.3, 0.7, 1.1, 5.0, 5.0, 5.0)):
        outs = [c.step(Q0, QDOT, f_n * N_W, ref(0.01 * i), 0.05) for c in (fast, full)]
        np.testing.assert_allclose(outs[0].tau, outs[1].tau, rtol=1e-12, atol=1e-12)
        assert fast.h == pytest.approx(full.h, rel=1e-12)
    assert fast.h == pytest.approx(2.0 * 500.0 / 6000.0)  # the scaled bound is active


def test_set_k_s_keeps_lambda2_h_continuous_and_returns_to_the_gains(model):
    ctrl = HybridForceController(model, law(model))
    ctrl.h = -0.3
    r0, _ = r_normal(ctrl, 1.0)  # df_n = 0: r_n = -lambda2 h
    ctrl.set_k_s(500.0)
    assert ctrl.h == pytest.approx(-0.3 * 0.1 / 1.2)
    assert r_normal(ctrl, 1.0)[0] == pytest.approx(r0)
    ctrl.set_gains(dataclasses.replace(ctrl.gains, f_d=2.0))  # a parameter set keeps k_s
    assert (ctrl.k_s, ctrl.lambda2) == (500.0, pytest.approx(1.2))
    ctrl.set_gains(dataclasses.replace(ctrl.gains, f_d=1.0))
    ctrl.set_k_s(None)
    assert (ctrl.k_s, ctrl.lambda2) == (6000.0, 0.1) and ctrl.h == pytest.approx(-0.3)
    # with a force error the c lambda1 df_n term does change: the loop gain is the point
    ctrl.set_k_s(500.0)
    assert r_normal(ctrl, 1.5)[0] - r_normal(ctrl, 1.0)[0] == pytest.approx(-40.0 * 0.5 / 500.0)


def test_rdot_holds_the_term_of_the_varying_compliance(model):
    """
    rdot_n is the derivative of r_n.

    With k_s ramping at d ln k_s/dt = rho and h held, r_n changes by -dc lambda1 df_n per unit
    time, which the rdot term supplies.
    """
    ctrl = HybridForceController(model, law(model))
    f_n, rho, dt = 1.4, -3.0, 1e-4
    ctrl.set_k_s(800.0, 0.0)
    r_a, rdot_0 = r_normal(ctrl, f_n)
    ctrl.set_k_s(800.0, rho)
    rdot_rho = r_normal(ctrl, f_n)[1]
    ctrl.set_k_s(800.0 * math.exp(rho * dt), rho)
    r_b = r_normal(ctrl, f_n)[0]
    assert rdot_rho - rdot_0 == pytest.approx((r_b - r_a) / dt, rel=1e-3)
    assert rdot_rho - rdot_0 == pytest.approx(rho * 40.0 * 0.4 / 800.0)


@pytest.mark.parametrize('k_s, rate', [(0.0, 0.0), (-1.0, 0.0), (math.nan, 0.0),
                                       (math.inf, 0.0), ('500', 0.0), (500.0, math.nan)])
def test_set_k_s_rejects_bad_values(model, k_s, rate):
    ctrl = HybridForceController(model, law(model))
    with pytest.raises(ControlError):
        ctrl.set_k_s(k_s, rate)
    assert ctrl.k_s == 6000.0


def test_set_k_s_allocates_nothing_that_stays(model):
    ctrl = HybridForceController(model, law(model))
    values = [float(k) for k in np.geomspace(300.0, 6000.0, 2000)]
    tracemalloc.start()
    for i, k_s in enumerate(values):
        if i == 10:
            base = tracemalloc.take_snapshot()
        ctrl.set_k_s(k_s, -1.0)
    grown = sum(s.size_diff for s in tracemalloc.take_snapshot().compare_to(base, 'filename')
                if 'control_law' in s.traceback[0].filename)
    tracemalloc.stop()
    assert grown < 512, grown


# ---------------------------------------------------------------- parameters
def test_stiffness_group_is_the_config_dataclass(model):
    specs = {s.name: s for s in CONTROLLER_SCHEMA if s.group == 'stiffness'}
    shared = {'k_max', 'k_s0', 'force_filter_hz'}
    fields = {f.name for f in dataclasses.fields(StiffnessConfig)}
    assert set(STIFFNESS_FIELDS) == set(specs)
    assert set(STIFFNESS_FIELDS.values()) == fields - shared
    default = build_params(model).stiffness
    assert default == StiffnessConfig()  # schema defaults == dataclass defaults
    assert specs['stiffness_estimation'].default is True
    p = build_params(model, {'k_min': 100.0, 'stiffness_k_hat0': 900.0, 'k_max': 5000.0,
                             'k_s': 4000.0, 'force_filter_hz': 100.0,
                             'stiffness_estimation': False, 'stiffness_k_s_rate_up': 5.0})
    assert (p.stiffness.k_min, p.stiffness.k_hat0, p.stiffness.k_max, p.stiffness.k_s0,
            p.stiffness.force_filter_hz, p.stiffness.enabled, p.stiffness.k_s_rate_up) == (
        100.0, 900.0, 5000.0, 4000.0, 100.0, False, 5.0)


@pytest.mark.parametrize('values, name', [
    ({'stiffness_k_hat0': 10.0}, 'stiffness_k_hat0'), ({'k_min': 7000.0}, 'k_min'),
    ({'stiffness_valid_tol': 1.0}, 'stiffness_valid_tol'),
    ({'stiffness_k_max_margin': 1.0}, 'stiffness_k_max_margin'),
    ({'stiffness_estimation': 'yes'}, 'stiffness_estimation'),
    ({'stiffness_time_constant': 0.0}, 'stiffness_time_constant'),
    ({'k_min': math.nan}, 'k_min')])
def test_stiffness_values_are_rejected_naming_the_parameter(model, values, name):
    with pytest.raises(ParameterValidationError, match=rf'(?<!\w){name}(?!\w)'):
        build_params(model, values)


def test_eq_29_at_the_estimate_is_enforced_only_when_it_is_on(model):
    """
    lambda1^2 > 2 lambda2 k_s.

    With k_s = 8000 > k_max the literal (29) holds (1600 > 1200) but the loop at k_s = k_hat would
    not be damped by 1/sqrt(2) (1600 = 1600).
    """
    with pytest.raises(ParameterValidationError, match='k_s = k_hat'):
        build_params(model, {'k_s': 8000.0})
    build_params(model, {'k_s': 8000.0, 'stiffness_estimation': False})
    with pytest.raises(ParameterValidationError, match='eq. \\(29\\) needs'):  # literal first
        build_params(model, {'lambda2': 0.2})


# ---------------------------------------------------------------- delay margin
def test_margin_with_the_estimate_is_the_worst_over_the_k_s_it_may_command(model):
    p = build_params(model)
    points = estimate_operating_points(p.law, p.stiffness)
    k_s = sorted({g.k_s for g, _ in points})
    assert len(k_s) == K_S_GRID and k_s[0] == pytest.approx(50.0) and k_s[-1] == 6000.0
    assert all(g.lambda2 * g.k_s == pytest.approx(0.1 * 6000.0) for g, _ in points)
    assert max(k / g.k_s for g, k in points) == pytest.approx(1.15)  # 1 + 3 valid_tol
    on = delay_margin(model, p.law, Q0, 200.0, stiffness=p.stiffness)
    off = delay_margin(model, p.law, Q0, 200.0)
    assert on < off  # measured 7.86 ms against 10.38 ms
    assert delay_margin(model, p.law, Q0, 200.0,
                        stiffness=dataclasses.replace(p.stiffness, enabled=False)) == off
    assert estimate_operating_points(p.law, dataclasses.replace(p.stiffness, enabled=False)) == []
    M = np.linalg.eigvalsh(np.linalg.inv(
        (J := model.kinematics(Q0, np.zeros(2)).J_ee) @ model.inertia_inverse(Q0) @ J.T))
    g_lo, k_lo = min(points, key=lambda gk: gk[0].k_s - gk[1])  # k_s = 50, k = 57.5
    assert on <= min(axis_margin(g_lo, m, 0.0, k_lo, 200.0) for m in M) + 1e-3


def test_runtime_validate_and_delay_margin_use_the_same_worst_case(model):
    rt = ControllerRuntime(model, build_params(model))
    rt.on_joint_state(list(model.joint_names), Q0, np.zeros(2), 0.0)
    p = rt.params
    assert rt.delay_margin() == delay_margin(model, p.law, Q0, 200.0, stiffness=p.stiffness)
    with pytest.raises(ParameterValidationError, match='delay margin of 7.86 ms'):
        rt.validate({'min_delay_margin': 0.009})
    rt.validate({'min_delay_margin': 0.009, 'stiffness_estimation': False})  # 10.38 ms


# ---------------------------------------------------------------- StiffnessLoop
def make_loop(model, **values):
    params = build_params(model, values)
    ctrl = HybridForceController(model, params.law)
    loop = StiffnessLoop(params.stiffness, params.law.n)
    loop.configure(params.stiffness, params.law.n, ctrl)
    return loop, ctrl, params


def press(loop, ctrl, k, touching=True, offset=0.0, **kw) -> tuple[float, float]:
    """
    Feed a synthetic press on a surface of stiffness k as new states (x_n = -y).

    Returns the last (f_n, x_n).
    """
    f_n, x_n = synthetic(k, **kw)
    for f, x in zip(f_n, x_n):
        loop.update(ctrl, float(f), np.array([1.0, -(x + offset), 0.0]), DT, DT, touching)
    return float(f_n[-1]), float(x_n[-1] + offset)


def hold(loop, ctrl, f_n, x_n, steps, touching=True) -> None:
    """Steady contact (or lifted off): the same sample as new states."""
    for _ in range(steps):
        loop.update(ctrl, f_n, np.array([1.0, -x_n, 0.0]), DT, DT, touching)


def test_loop_sets_the_law_k_s_and_reports_nan_until_valid(model):
    loop, ctrl, _ = make_loop(model)
    assert math.isnan(loop.k_hat) and ctrl.k_s == 6000.0
    st = loop.status(ctrl)
    assert not st.near_k_max  # the prior sits at k_max: not a warning
    press(loop, ctrl, 500.0, duration=0.02)
    assert math.isnan(loop.k_hat) and ctrl.k_s == 6000.0  # not valid yet: k_s held
    last = press(loop, ctrl, 500.0)
    st = loop.status(ctrl)
    assert loop.k_hat == pytest.approx(500.0, rel=1e-4) and st.valid and st.enabled
    assert ctrl.k_s == st.k_s and st.k_s < 6000.0  # falling, rate-limited (10/s)
    hold(loop, ctrl, *last, 3000)  # steady contact: the estimate stays, k_s arrives
    assert ctrl.k_s == pytest.approx(500.0, rel=1e-4) and loop.status(ctrl).changes == 0
    assert ctrl.lambda2 == pytest.approx(0.1 * 6000.0 / ctrl.k_s)


def test_loop_disabled_reports_but_leaves_the_law_alone(model):
    loop, ctrl, _ = make_loop(model, stiffness_estimation=False)
    press(loop, ctrl, 500.0)
    assert loop.k_hat == pytest.approx(500.0, rel=1e-4)
    assert (ctrl.k_s, ctrl.lambda2) == (6000.0, 0.1) and not loop.status(ctrl).enabled


def test_switching_on_starts_from_the_law_k_s_and_off_returns_at_once(model):
    loop, ctrl, params = make_loop(model, stiffness_estimation=False, stiffness_k_hat0=1000.0)
    last = press(loop, ctrl, 500.0)
    on = dataclasses.replace(params.stiffness, enabled=True)
    loop.configure(on, params.law.n, ctrl)
    assert ctrl.k_s == 6000.0  # no jump to the prior or the estimate
    hold(loop, ctrl, *last, 1)
    assert 6000.0 * math.exp(-10.0 * DT) <= ctrl.k_s < 6000.0
    hold(loop, ctrl, *last, 1000)
    ctrl.h = -0.2
    lambda2_h = ctrl.lambda2 * ctrl.h
    loop.configure(params.stiffness, params.law.n, ctrl)  # off again
    assert (ctrl.k_s, ctrl.lambda2) == (6000.0, 0.1)
    assert ctrl.lambda2 * ctrl.h == pytest.approx(lambda2_h)


def test_a_set_keeps_the_estimate_unless_prior_bounds_or_normal_change(model):
    loop, ctrl, params = make_loop(model)
    press(loop, ctrl, 500.0)
    est = loop.estimator
    before = (est.k_hat, est.k_hat_std, est.samples_used, est.valid, ctrl.k_s)
    other = build_params(model, {'f_d': 2.0, 'stiffness_k_s_rate_up': 5.0})
    loop.configure(other.stiffness, other.law.n, ctrl)
    assert (est.k_hat, est.k_hat_std, est.samples_used, est.valid, ctrl.k_s) == before
    tilted = build_params(model, {'n': [0.1, -1.0, 0.0]})
    loop.configure(tilted.stiffness, tilted.law.n, ctrl)
    assert est.k_hat == before[0] and not est.valid and loop.k_hat == before[0]
    prior = build_params(model, {'stiffness_k_hat0': 2000.0})
    loop.configure(prior.stiffness, prior.law.n, ctrl)
    assert est.k_hat == 2000.0 and math.isnan(loop.k_hat) and ctrl.k_s == before[-1]


def test_a_contact_loss_makes_the_surface_unknown_and_k_s_returns(model):
    """
    Lifted off: NaN, the fit restarts from the prior.

    k_s jumps back to k_s0 = 6000 (lambda2 h continuous); the next surface (1 cm further, 1200 N/m)
    is learned alone.
    """
    loop, ctrl, _ = make_loop(model)
    last = press(loop, ctrl, 500.0)
    hold(loop, ctrl, *last, 1000)
    assert ctrl.k_s == pytest.approx(500.0, rel=1e-3) and loop.contacts == 1
    ctrl.h = -0.1
    lambda2_h = ctrl.lambda2 * ctrl.h
    f_n, x_n = synthetic(1200.0)
    x_n = x_n + 0.01
    hold(loop, ctrl, 0.0, float(x_n[0]), 100, touching=False)  # lifted off, moving there
    st = loop.status(ctrl)
    assert math.isnan(st.k_hat) and st.restarts == 1 and st.changes == 0 and not st.valid
    assert (ctrl.k_s, ctrl.lambda2) == (6000.0, 0.1)
    assert ctrl.lambda2 * ctrl.h == pytest.approx(lambda2_h)
    for f, x in zip(f_n, x_n):
        loop.update(ctrl, float(f), np.array([1.0, -x, 0.0]), DT, DT, True)
    assert loop.contacts == 2 and loop.k_hat == pytest.approx(1200.0, rel=1e-4)


def test_a_change_under_the_tool_makes_the_surface_unknown(model):
    """(S9) through the loop: the force leaves the fitted line at constant x."""
    loop, ctrl, _ = make_loop(model)
    f, x = press(loop, ctrl, 500.0)
    hold(loop, ctrl, f, x, 1000)
    hold(loop, ctrl, f + 1.0, x, 10)
    st = loop.status(ctrl)
    assert st.changes == st.restarts == 1 and math.isnan(st.k_hat) and ctrl.k_s == 6000.0


@pytest.mark.parametrize('k, k_max, near, known', [(5000.0, 6000.0, True, True),
                                                   (1700.0, 6000.0, False, True),
                                                   (3000.0, 2000.0, True, False)])
def test_near_k_max_warns_for_a_known_or_saturated_estimate(model, k, k_max, near, known):
    """
    (S8) on an estimate, not on the prior.

    A surface stiffer than k_max holds k_hat at the bound (not valid: reported NaN, k_s stays at
    k_max) and warns.
    """
    loop, ctrl, _ = make_loop(model, k_max=k_max, k_s=k_max)
    press(loop, ctrl, k)
    st = loop.status(ctrl)
    assert st.near_k_max is near and (not math.isnan(st.k_hat)) is known
    assert st.saturated is (not known)
