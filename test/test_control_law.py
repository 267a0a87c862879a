"""
Unit relations of the control law (eqs. (8), (11), (26), (29)) on the bundled 2-link arm.

Pure numpy + pinocchio: no ROS. The closed-loop checks use the offline plant
(:class:`ArmSimulator`) and the paper's start pose.
"""
from __future__ import annotations

import math

from hybrid_force_controller.core.config.params import (build_params, check_stability,
                                                        ParameterValidationError)
from hybrid_force_controller.core.law.control_law import (adapt_theta, ControlError,
                                                          HybridForceController, small_inverse)
from hybrid_force_controller.core.law.reference import blend_start, Reference, SineReference
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.environment import ElasticSurface
from hybrid_force_controller.core.offline.scenario import PAPER_Q0
from hybrid_force_controller.core.offline.simulator import ArmSimulator
from hybrid_force_controller.core.runtime.effort import EffortLimiter
import numpy as np
import pinocchio as pin
import pytest


Q0 = np.array(PAPER_Q0)
DT = 1e-3


def make_ctrl(model: RobotModel, **overrides) -> HybridForceController:
    """
    Build a controller with the gains of ``build_params(model, overrides)``.

    ``ctrl.full`` is the whole parameter set (for the reference).
    """
    params = build_params(model, overrides)
    ctrl = HybridForceController(model, params.law)
    ctrl.full = params
    return ctrl


def sine_ref(params, t: float = 0.3) -> Reference:
    rt = params.runtime
    return SineReference(rt.ref_center, rt.ref_amplitude, rt.ref_omega)(t)


def task_velocity_from_pinocchio(model: RobotModel, q, qdot) -> np.ndarray:
    """Compute xdot = J(q) qdot independently of RobotModel.kinematics."""
    J = pin.computeFrameJacobian(model.model, model.model.createData(), np.asarray(q, float),
                                 model.frame_id, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
    return (J[:3] @ np.asarray(qdot, float))[list(model.task_axes)]


# ---------------------------------------------------------------- eqs. (8) and (11)
def test_r_does_not_depend_on_the_velocity(model):
    """Scaled eq. (11): r has no velocity (nor force-rate) term; e does."""
    ctrl = make_ctrl(model)
    ctrl.h = 0.37  # a non-zero force integral, so its term is present
    n = ctrl.gains.n[list(model.task_axes)]
    ref = sine_ref(ctrl.full)
    f = np.array([0.0, -1.4])  # task coordinates (x, y): 1.4 N along n = -y
    kin0 = model.kinematics(Q0, np.array([0.1, -0.2]))
    r0 = ctrl.reference_velocity(kin0, ref, f)[0]
    e0 = kin0.xdot - r0
    for dqdot in ([0.5, 0.5], [0.7, -0.7], [3.0, 2.0], [-0.4, 0.0]):
        kin1 = model.kinematics(Q0, np.array([0.1, -0.2]) + dqdot)
        r1 = ctrl.reference_velocity(kin1, ref, f)[0]
        e1 = kin1.xdot - r1
        assert float(n @ r1) == pytest.approx(float(n @ r0), abs=1e-15)
        np.testing.assert_allclose(r1, r0, rtol=0.0, atol=1e-15)
        # ... while the perturbation did change the normal velocity and e
        assert abs(float(n @ (kin1.xdot - kin0.xdot))) > 1e-3
        assert abs(float(n @ (e1 - e0))) > 1e-3


def test_r_matches_the_documented_formula(model):
    """Check r = (I - S)(xdot_d - l1 dx) - n (c l1 df_n + l2 h), c = 1 / k_s."""
    ctrl = make_ctrl(model, lambda1=30.0, lambda2=0.05, k_s=4000.0, k_max=4000.0, f_d=2.0)
    ctrl.h = -0.2
    ax = list(model.task_axes)
    n = ctrl.gains.n[ax]
    ref = sine_ref(ctrl.full, 0.8)
    kin = model.kinematics(Q0, np.array([0.2, 0.1]))
    f = np.array([0.3, -2.5])
    r, _, df_n, _, _ = ctrl.reference_velocity(kin, ref, f)
    assert df_n == pytest.approx(2.5 - 2.0)
    P_t = np.eye(2) - np.outer(n, n)
    expected = (P_t @ (ref.xdot_d_W[ax] - 30.0 * (kin.x - ref.x_d_W[ax]))
                - n * (30.0 / 4000.0 * 0.5 + 0.05 * (-0.2)))
    np.testing.assert_allclose(r, expected, rtol=1e-12, atol=1e-15)


def test_returned_e_is_xdot_minus_r(model):
    """Eq. (8): e = xdot - r, with xdot from pinocchio directly."""
    ctrl = make_ctrl(model)
    rng = np.random.default_rng(0)
    ref = sine_ref(ctrl.full, 1.1)
    for _ in range(5):
        q = Q0 + rng.uniform(-0.2, 0.2, 2)
        qdot = rng.uniform(-1.0, 1.0, 2)
        f_W = np.array([0.0, -rng.uniform(0.5, 2.0), 0.0])
        kin = model.kinematics(q, qdot)
        r = ctrl.reference_velocity(kin, ref, f_W[:2])[0]  # r with h before step
        out = ctrl.step(q, qdot, f_W, ref, DT)
        xdot = task_velocity_from_pinocchio(model, q, qdot)
        np.testing.assert_allclose(out.e, xdot - r, rtol=0.0, atol=1e-12)
        n = ctrl.gains.n[list(model.task_axes)]
        assert out.r_n == pytest.approx(float(n @ r), abs=1e-15)


def _record_r(model: RobotModel, k_surface: float, steps: int = 1500):
    """
    Run a closed loop of the paper's start (blend into the sine) on a surface of stiffness k.

    Returns r(t_i), rdot(t_i) and the normal force f_n(t_i) at every tick; r is evaluated
    with the force integral h the controller holds at that tick.
    """
    ctrl = make_ctrl(model)
    p, rt = ctrl.gains, ctrl.full.runtime
    p0 = model.kinematics(Q0, np.zeros(2)).p_W
    sim = ArmSimulator(model, ElasticSurface.create(k_surface, p0, p.n), Q0, substeps=8)
    sine = SineReference(rt.ref_center, rt.ref_amplitude, rt.ref_omega)
    offset = (np.eye(3) - np.outer(p.n, p.n)) @ (p0 - sine(0.0).x_d_W)
    n = p.n[list(model.task_axes)]
    rs, rdots, fns = [], [], []
    meas = sim.measure()
    for i in range(steps):
        ref = blend_start(sine(i * DT), offset, i * DT, rt.ref_blend_time)
        f = meas.f_W[list(model.task_axes)]
        r, rdot = ctrl.reference_velocity(model.kinematics(meas.q, meas.qdot), ref, f)[:2]
        rs.append(r)
        rdots.append(rdot)
        fns.append(float(n @ f))
        meas = sim.step(ctrl.step(meas.q, meas.qdot, meas.f_W, ref, DT).tau, DT)
    return np.array(rs), np.array(rdots), np.array(fns), n


def _fd_mismatch(model, k_surface):
    r, rdot, f_n, n = _record_r(model, k_surface)
    fd = (r[2:] - r[:-2]) / (2 * DT)
    # in firm contact at all three samples (h integrates there, f = k depth)
    ok = (f_n[:-2] > 0.2) & (f_n[1:-1] > 0.2) & (f_n[2:] > 0.2)
    assert ok.sum() > 1000
    err = (fd - rdot[1:-1])[ok]
    return err, rdot[1:-1][ok], n


def test_rdot_is_the_time_derivative_of_r_when_k_equals_k_s(model):
    """
    Central differences of r along a closed-loop run match rdot (no accelerations needed).

    Both the tangential part and the normal (force) part.
    """
    err, rdot, n = _fd_mismatch(model, k_surface=6000.0)  # = k_s default
    assert np.abs(rdot).max() > 0.1  # a non-trivial signal (m/s^2)
    t_hat = np.array([n[1], -n[0]])
    assert np.abs(err @ t_hat).max() < 5e-3
    assert np.abs(err @ n).max() < 5e-3
    assert np.abs(rdot @ n).max() > 0.05  # the normal part is exercised too


def test_rdot_normal_part_differs_when_k_is_not_k_s(model):
    """
    Control: with k = k_s / 2 the model-based force rate k_s n^T xdot is wrong by 2x.

    The finite-difference check above then fails on the normal component.
    """
    err, _, n = _fd_mismatch(model, k_surface=3000.0)
    assert np.abs(err @ n).max() > 0.05


# ---------------------------------------------------------------- eq. (29)
def test_check_stability_accepts_paper_gains_up_to_the_strict_bound():
    assert check_stability(40.0, 0.1, 6000.0) is None  # 1600 > 1200
    assert check_stability(40.0, 0.1, 7999.0) is None  # 1600 > 1599.8
    with pytest.raises(ParameterValidationError):
        check_stability(40.0, 0.1, 8000.0)  # 1600 = 1600: eq. (29) is strict


def test_check_stability_rejects_and_states_both_sides():
    with pytest.raises(ParameterValidationError) as exc:
        check_stability(10.0, 0.1, 6000.0)
    msg = str(exc.value)
    assert '100' in msg and '1200' in msg


def test_check_stability_boundary_is_strict():
    with pytest.raises(ParameterValidationError):
        check_stability(40.0, 0.5, 1600.0)  # 1600 == 1600


@pytest.mark.parametrize('args', [(math.nan, 0.1, 6000.0), (40.0, math.nan, 6000.0),
                                  (40.0, 0.1, math.nan)])
def test_check_stability_rejects_nan(args):
    with pytest.raises(ParameterValidationError):
        check_stability(*args)


# ---------------------------------------------------------------- eq. (26)
def test_adapt_theta_is_euler_step_inside_the_box():
    rng = np.random.default_rng(0)
    G = rng.normal(size=(2, 2))
    Gamma_inv = np.linalg.inv(G @ G.T + 2 * np.eye(2))
    Y = rng.normal(size=(3, 2))
    e = rng.normal(size=3)
    theta = np.array([1.0, 0.8])
    dt = 1e-3
    out = adapt_theta(theta, Gamma_inv, Y, e, dt, np.zeros(2), np.full(2, 10.0))
    np.testing.assert_allclose(out, theta - dt * Gamma_inv @ Y.T @ e, rtol=1e-14, atol=0)
    assert not np.allclose(out, theta)


def test_adapt_theta_is_clipped_to_the_box():
    Gamma_inv = np.eye(2)
    Y = np.eye(2)
    lo, hi = np.array([0.5, 0.5]), np.array([2.0, 2.0])
    theta = np.array([1.0, 1.0])
    # the unclipped step would go to [1 - 10, 1 + 10]
    out = adapt_theta(theta, Gamma_inv, Y, np.array([10.0, -10.0]), 1.0, lo, hi)
    np.testing.assert_array_equal(out, [0.5, 2.0])
    # one component clipped, the other a plain step
    out = adapt_theta(theta, Gamma_inv, Y, np.array([0.2, -10.0]), 1.0, lo, hi)
    np.testing.assert_allclose(out, [0.8, 2.0], rtol=1e-15)


def test_step_adapts_with_k_a_times_e(model):
    """
    The update in step() is (26) on k_a e: theta - dt Gamma^-1 Y_x^T (k_a e).

    A short dt keeps the step inside the projection box.
    """
    ctrl = make_ctrl(model, gamma=[70.0, 50.0], k_a=3000.0, adapt_error_limit=1e3)
    p = ctrl.gains
    q, qdot = Q0 + 0.05, np.array([0.3, -0.1])
    f_W = np.array([0.0, -1.2, 0.0])
    ref = sine_ref(ctrl.full, 0.5)
    theta0 = ctrl.theta_hat.copy()
    kin = model.kinematics(q, qdot)
    r, rdot = ctrl.reference_velocity(kin, ref, f_W[:2])[:2]
    e = kin.xdot - r
    Y_x = model.regressor_x(q, qdot, r, rdot)
    dt = 1e-5
    out = ctrl.step(q, qdot, f_W, ref, dt)
    expected = theta0 - dt * np.linalg.inv(p.Gamma) @ Y_x.T @ (3000.0 * e)
    assert np.all((expected > p.theta_min) & (expected < p.theta_max))
    assert np.abs(expected - theta0).min() > 1e-3  # a visible step
    np.testing.assert_allclose(out.theta_hat, expected, rtol=1e-9, atol=1e-12)


def test_adaptation_integrates_a_saturated_error(model):
    """
    |e| above adapt_error_limit.

    The update keeps its direction, its size is that of an error of norm adapt_error_limit (a
    transient cannot throw theta_hat).
    """
    q, qdot = Q0 + 0.05, np.array([0.3, -0.1])
    f_W, dt = np.array([0.0, -1.2, 0.0]), 1e-5
    steps = {}
    for limit in (1e3, 0.01):
        ctrl = make_ctrl(model, adapt_error_limit=limit)
        theta0 = ctrl.theta_hat.copy()
        out = ctrl.step(q, qdot, f_W, sine_ref(ctrl.full, 0.5), dt)
        steps[limit] = (out.theta_hat - theta0, float(np.linalg.norm(out.e)))
    (free, e_norm), (saturated, _) = steps[1e3], steps[0.01]
    assert e_norm > 0.01
    np.testing.assert_allclose(saturated, free * (0.01 / e_norm), rtol=1e-9)


# ---------------------------------------------------------------- output limits
@pytest.mark.parametrize('f_W', [[0.0, -1e4, 0.0], [0.0, 1e4, 0.0], [1e4, 1e4, 0.0],
                                 [-1e4, 0.0, 0.0]])
def test_limited_effort_never_exceeds_limits(model, f_W):
    ctrl = make_ctrl(model)
    limiter = EffortLimiter(np.array([30.0, 20.0]))
    rng = np.random.default_rng(1)
    ref = sine_ref(ctrl.full)
    for _ in range(20):
        q = Q0 + rng.uniform(-0.3, 0.3, 2)
        out = ctrl.step(q, rng.uniform(-2, 2, 2), np.array(f_W), ref, DT)
        tau, saturated = limiter(out.tau)
        assert np.all(np.isfinite(tau))
        assert np.all(np.abs(tau) <= [30.0, 20.0])
        assert saturated and np.abs(out.tau).max() > 30.0  # the law's effort was beyond


def test_max_effort_rate_limits_the_per_tick_change(model):
    rate = 0.5
    ctrl = make_ctrl(model)
    limits = ctrl.full.runtime.effort_limits
    limited, free = EffortLimiter(limits, rate), EffortLimiter(limits)
    ref = sine_ref(ctrl.full)
    taus, free_taus = [], []
    for i in range(30):
        f_W = np.array([0.0, -1e4 if i % 2 else 1e4, 0.0]) * (1 + 0.01 * i)
        if i == 10:
            f_W = np.array([0.0, -1.0, 0.0])
        tau = ctrl.step(Q0, np.zeros(2), f_W, ref, DT).tau
        taus.append(limited(tau)[0])
        free_taus.append(free(tau)[0])
    d = np.abs(np.diff(taus, axis=0))
    assert d.max() <= rate + 1e-12
    assert np.abs(np.diff(free_taus, axis=0)).max() > 10 * rate  # the limit was active
    assert np.all(np.abs(taus) <= limits)
    limited.reset()  # a restart does not rate-limit against the last command
    np.testing.assert_array_equal(limited(free_taus[0])[0], free_taus[0])


def test_limiter_reports_no_saturation_within_the_limits():
    limiter = EffortLimiter(np.array([30.0, 20.0]))
    tau = np.array([29.0, -19.5])
    out, saturated = limiter(tau)
    np.testing.assert_array_equal(out, tau)
    assert saturated is False
    assert limiter(np.array([29.0, -20.5]))[1] is True


@pytest.mark.parametrize('size', [2, 3, 4])
def test_small_inverse_matches_numpy(size):
    """The closed forms (2 x 2, 3 x 3) and the general case invert like numpy.linalg.inv."""
    rng = np.random.default_rng(size)
    for _ in range(20):
        A = rng.normal(size=(size, size)) + 2.0 * np.eye(size)
        np.testing.assert_allclose(small_inverse(A), np.linalg.inv(A), rtol=1e-12, atol=1e-12)
    with pytest.raises(np.linalg.LinAlgError):
        small_inverse(np.ones((size, size)))


# ---------------------------------------------------------------- bad input
@pytest.mark.filterwarnings('ignore::RuntimeWarning')
@pytest.mark.parametrize('which,value', [
    ('q', [math.nan, 0.9]), ('q', [math.inf, 0.9]), ('qdot', [0.0, math.nan]),
    ('qdot', [-math.inf, 0.0]), ('f', [0.0, math.nan, 0.0]), ('f', [math.inf, -1.0, 0.0]),
])
def test_non_finite_input_raises_and_keeps_state(model, which, value):
    ctrl = make_ctrl(model)
    ref = sine_ref(ctrl.full)
    good = {'q': Q0.copy(), 'qdot': np.zeros(2), 'f': np.array([0.0, -1.5, 0.0])}
    ctrl.step(good['q'], good['qdot'], good['f'], ref, DT)  # h and theta_hat move
    theta, h = ctrl.theta_hat.copy(), ctrl.h
    bad = dict(good, **{which: np.array(value)})
    with pytest.raises(ControlError):
        ctrl.step(bad['q'], bad['qdot'], bad['f'], ref, DT)
    np.testing.assert_array_equal(ctrl.theta_hat, theta)
    assert ctrl.h == h


@pytest.mark.parametrize('dt', [-1e-3, math.nan, math.inf])
def test_bad_dt_raises(model, dt):
    ctrl = make_ctrl(model)
    with pytest.raises(ControlError):
        ctrl.step(Q0, np.zeros(2), np.array([0.0, -1.0, 0.0]), sine_ref(ctrl.full), dt)


def test_zero_dt_recomputes_the_effort_and_integrates_nothing(model):
    """A tick without a new state: the same command, theta_hat and h unchanged."""
    ctrl = make_ctrl(model)
    ref, f_W = sine_ref(ctrl.full), np.array([0.0, -1.5, 0.0])
    q, qdot = Q0 + 0.02, np.array([0.2, -0.1])
    ctrl.step(q, qdot, f_W, ref, DT)
    theta, h = ctrl.theta_hat.copy(), ctrl.h
    again = [ctrl.step(q, qdot, f_W, ref, 0.0).tau for _ in range(3)]
    np.testing.assert_array_equal(ctrl.theta_hat, theta)
    assert ctrl.h == h
    np.testing.assert_array_equal(again[0], again[2])
    ctrl.step(q, qdot, f_W, ref, DT)  # control: a positive dt does integrate
    assert not np.array_equal(ctrl.theta_hat, theta) and ctrl.h != h
    moved_again = ctrl.step(q, qdot, f_W, ref, 0.0)
    assert not np.array_equal(moved_again.tau, again[0])
