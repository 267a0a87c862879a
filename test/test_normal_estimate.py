"""
The surface-normal estimate (core/law/normal_estimate.py) on synthetic force/velocity streams.

Streams at 1 kHz: the force the tool exerts, ``f_n n + mu f_n u`` (Coulomb friction along the
sliding velocity u), plus noise (sigma 0.05 N, through the controller's 200 Hz filter), the
velocity with noise (sigma 2 mm/s) and a 3 mm/s, 7 Hz ripple along the normal (the force loop);
f_n = 5 N; the initial guess n = [0, 0, -1]. Scenarios of issue 24: a plane tilted 0.3 rad about
x and about y (the tool going back and forth along x), a cylinder (R 0.3 m) traversed across its
axis, a sphere (R 0.5 m) with a 10 cm square over its top.

* the estimate converges within the issue's targets from 2 s after sliding begins: <= 2 deg on
  the planes, <= 3 deg on the curved surfaces, with mu 0.3 and 0.5; mu_hat converges to mu;
* negative control: mu 0.5 without the friction removal (and without the velocity fusion) errs
  by about atan(0.5) = 26.6 deg;
* n_hat never turns faster than the rate limit; it follows a fixed measurement with the time
  constant; the gates hold it (bit for bit) at rest, out of contact, below the force floor, on a
  non-finite or implausible sample; it is always a finite unit vector; bad arguments and
  settings are refused with typed errors (and as parameters, with the rate bound of
  docs/design.md).
"""
from __future__ import annotations

import math

from hybrid_force_controller.core.config.params import (build_params, normal_rate_bound,
                                                        ParameterValidationError)
from hybrid_force_controller.core.law.normal_estimate import (NormalConfig, NormalConfigError,
                                                              NormalEstimateError,
                                                              NormalEstimator)
from hybrid_force_controller.core.model.robot_model import RobotModel
import numpy as np
import pytest

DT = 1e-3
T_RUN = 16.0
F_N = 5.0
N0 = (0.0, 0.0, -1.0)  # the controller's initial guess: pressing down


def _rot(axis: str, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return {'x': np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            'y': np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])}[axis]


def plane(axis: str, tilt: float = 0.3):
    """Return (v, n) arrays: a plane tilted about ``axis``, x = 5 cm sin(t) along it."""
    t = np.arange(int(T_RUN / DT)) * DT
    R = _rot(axis, tilt)
    along = R @ [1.0, 0.0, 0.0]
    n = np.tile(R @ [0.0, 0.0, -1.0], (t.size, 1))
    return np.outer(0.05 * np.cos(t), along), n


def cylinder(R: float = 0.3, amp: float = 0.1, w: float = 0.5):
    """Return (v, n) across the cylinder of axis y, +-10 cm of arc (n turns up to 0.17 rad/s)."""
    t = np.arange(int(T_RUN / DT)) * DT
    th, thd = amp / R * np.sin(w * t), amp / R * w * np.cos(w * t)
    v = (R * thd)[:, None] * np.column_stack((np.cos(th), 0 * th, -np.sin(th)))
    return v, -np.column_stack((np.sin(th), 0 * th, np.cos(th)))


def sphere(R: float = 0.5, half: float = 0.05, speed: float = 0.05):
    """Return (v, n): a 10 cm square over the top of a sphere at 5 cm/s."""
    t = np.arange(int(T_RUN / DT)) * DT
    corners = np.array([(half, half), (-half, half), (-half, -half), (half, -half)])
    s = (speed * t) % (8 * half)
    k = (s // (2 * half)).astype(int)
    a = (s - k * 2 * half) / (2 * half)
    c0, c1 = corners[k], corners[(k + 1) % 4]
    xy = c0 + a[:, None] * (c1 - c0)
    vxy = speed * (c1 - c0) / (2 * half)
    z = np.sqrt(R * R - np.sum(xy ** 2, axis=1))  # height above the centre
    vz = -np.sum(xy * vxy, axis=1) / z
    p_c = np.column_stack((xy, z))  # from the centre
    return np.column_stack((vxy, vz)), -p_c / R


SCENARIOS = {'plane_about_x': lambda: plane('x'), 'plane_about_y': lambda: plane('y'),
             'cylinder': cylinder, 'sphere': sphere}
TARGET_DEG = {'plane_about_x': 2.0, 'plane_about_y': 2.0, 'cylinder': 3.0, 'sphere': 3.0}


def stream(scenario: str, mu: float, seed: int = 0):
    """Return (f, v, n) rows: the filtered measured force, the measured velocity, the truth."""
    v, n = SCENARIOS[scenario]()
    rng = np.random.default_rng(seed)
    speed = np.linalg.norm(v, axis=1, keepdims=True)
    f = F_N * n + mu * F_N * v / np.maximum(speed, 1e-12) + rng.normal(0.0, 0.05, v.shape)
    a = -math.expm1(-2.0 * math.pi * 200.0 * DT)  # the controller's force filter
    for i in range(1, len(f)):
        f[i] = f[i - 1] + a * (f[i] - f[i - 1])
    ripple = 0.003 * np.sin(2.0 * math.pi * 7.0 * np.arange(len(v)) * DT)
    v_meas = v + rng.normal(0.0, 0.002, v.shape) + ripple[:, None] * n
    return f, v_meas, n


def errors_deg(est: NormalEstimator, f, v, n) -> tuple[np.ndarray, float | None]:
    """Feed the stream; return the angle to the truth per sample and when sliding began, s."""
    out, t_slide = np.empty(len(f)), None
    for i, (fi, vi) in enumerate(zip(f.tolist(), v.tolist())):
        est.update(fi, vi, DT, True)
        if t_slide is None and est.state == 'sliding':
            t_slide = i * DT
        out[i] = math.degrees(math.acos(min(1.0, float(np.dot(est.n_hat, n[i])))))
    return out, t_slide


def normal_error_deg(scenario: str, mu: float, config: NormalConfig) -> tuple[float, float]:
    """Return (largest error from 2 s after sliding began, mu_hat at the end)."""
    est = NormalEstimator(config, N0)
    err, t_slide = errors_deg(est, *stream(scenario, mu))
    assert t_slide is not None and t_slide < 1.0, t_slide
    return float(err[int((t_slide + 2.0) / DT):].max()), est.mu_hat


# ---------------------------------------------------------------- convergence
@pytest.mark.parametrize('mu', [0.3, 0.5])
@pytest.mark.parametrize('scenario', sorted(SCENARIOS))
def test_estimate_converges_within_the_issue_targets(scenario, mu):
    _, n = SCENARIOS[scenario]()
    start = math.degrees(math.acos(float(np.dot(N0, n[0]))))
    worst, mu_hat = normal_error_deg(scenario, mu, NormalConfig(enabled=True))
    print(f'{scenario} mu {mu}: initial error {start:.1f} deg, largest from 2 s after sliding '
          f'began {worst:.2f} deg, mu_hat {mu_hat:.3f}')
    assert worst <= TARGET_DEG[scenario]
    assert mu_hat == pytest.approx(mu, abs=0.02)


def test_without_friction_removal_friction_tilts_the_estimate_by_atan_mu():
    """Negative control: mu 0.5, removal and fusion off: the error is about atan(0.5)."""
    off = NormalConfig(friction_removal=False, velocity_fusion=0.0)
    worst_off, _ = normal_error_deg('plane_about_x', 0.5, off)
    worst_on, _ = normal_error_deg('plane_about_x', 0.5, NormalConfig())
    print(f'mu 0.5: removal off {worst_off:.2f} deg (atan 26.57), on {worst_on:.2f} deg')
    assert worst_off == pytest.approx(math.degrees(math.atan(0.5)), abs=2.0)
    assert worst_on <= 2.0


def test_velocity_fusion_alone_removes_the_friction():
    """Fusion weight 1 without the mu_hat removal: n_hat perpendicular to v (Yoshikawa)."""
    worst, _ = normal_error_deg('plane_about_y', 0.5, NormalConfig(friction_removal=False,
                                                                   velocity_fusion=1.0))
    assert worst <= 2.0


# ---------------------------------------------------------------- rate, filter, gates
def _sliding_sample(m_W, speed=0.05):
    """Return (f, v): a force along the unit ``m_W`` (5 N) and a velocity across it."""
    m = np.asarray(m_W, dtype=float)
    v = np.cross(m, [0.0, 1.0, 0.0] if abs(m[1]) < 0.9 else [1.0, 0.0, 0.0])
    return F_N * m, speed * v / np.linalg.norm(v)


@pytest.mark.parametrize('time_constant', [1e-3, 0.1])
def test_n_hat_never_turns_faster_than_the_rate_limit(time_constant):
    cfg = NormalConfig(rate_limit=0.5, time_constant=time_constant, velocity_fusion=0.0)
    est = NormalEstimator(cfg, N0)
    target = np.array([math.sin(1.2), 0.0, -math.cos(1.2)])  # 69 deg away
    f, v = _sliding_sample(target)
    prev = np.array(est.n_hat)
    for _ in range(1000):
        assert est.update(f, v, DT, True)
        now = np.array(est.n_hat)
        turned = math.acos(min(1.0, float(prev @ now)))
        assert turned <= 0.5 * DT * (1.0 + 1e-9) + 1e-12 and est.last_angle <= 0.5 * DT + 1e-15
        prev = now
    total = math.acos(min(1.0, float(np.dot(est.n_hat, N0))))
    assert total == pytest.approx(0.5, rel=1e-6)  # 1 s at the limit: 0.5 rad, still turning


def test_n_hat_follows_a_measurement_with_its_time_constant():
    est = NormalEstimator(NormalConfig(rate_limit=50.0, time_constant=0.1), N0)
    target = np.array([math.sin(0.1), 0.0, -math.cos(0.1)])
    f, v = _sliding_sample(target)
    for _ in range(100):  # one time constant
        est.update(f, v, DT, True)
    left = math.acos(min(1.0, float(np.dot(est.n_hat, target))))
    assert left == pytest.approx(0.1 * math.exp(-1.0), rel=1e-3)


@pytest.mark.parametrize('case', ['at_rest', 'no_contact', 'low_force', 'rejected',
                                  'implausible', 'degenerate'])
def test_gates_hold_n_hat(case):
    est = NormalEstimator(NormalConfig(), N0)
    tilted = np.array([math.sin(0.3), 0.0, -math.cos(0.3)])
    f, v = _sliding_sample(tilted)
    est.update(f, v, DT, True)  # one good sample, so mu_hat and n_hat are not the initial ones
    before, mu_before = est.n_hat, est.mu_hat
    contact = case != 'no_contact'
    if case == 'at_rest':  # static friction may lean the force by atan(mu): not used
        f, v = F_N * np.array([0.4, 0.0, -1.0]), np.array([0.004, 0.0, 0.003])
    elif case == 'low_force':
        f = 0.45 * tilted
    elif case == 'rejected':
        f = np.array([math.nan, 0.0, -5.0])
    elif case == 'implausible':  # a force pulling on the surface
        f = -F_N * tilted
    elif case == 'degenerate':  # all of it along v, removed by the fusion
        est.reconfigure(NormalConfig(velocity_fusion=1.0, friction_removal=False))
        f = v / np.linalg.norm(v) * F_N
    for _ in range(100):
        assert not est.update(f, v, DT, contact)
    assert est.n_hat == before  # bit for bit
    assert est.state == {'degenerate': 'implausible'}.get(case, case)
    if case != 'implausible' and case != 'degenerate':
        assert est.mu_hat == mu_before
    assert est.samples_rejected == (100 if case == 'rejected' else 0)


def test_n_hat_is_always_a_finite_unit_vector():
    rng = np.random.default_rng(5)
    est = NormalEstimator(NormalConfig(rate_limit=10.0, time_constant=1e-3), N0)
    scales = [1e-9, 1.0, 1e6, 1e150]
    for i in range(20000):
        f = rng.normal(size=3) * scales[i % 4]
        v = rng.normal(size=3) * scales[(i // 4) % 4]
        if i % 97 == 0:
            f[i % 3] = [math.nan, math.inf, -math.inf][i % 3]
        est.update(f, v, DT * (1 + i % 7), bool(i % 5))
        n = np.array(est.n_hat)
        assert np.all(np.isfinite(n)) and abs(float(n @ n) - 1.0) < 1e-12
    assert est.samples_used > 1000 and est.samples_rejected > 100


@pytest.mark.parametrize('dt', [0.0, -1e-3, math.nan, math.inf])
def test_bad_dt_is_refused(dt):
    est = NormalEstimator(NormalConfig(), N0)
    with pytest.raises(NormalEstimateError, match='dt must be finite and > 0'):
        est.update([0, 0, -5], [0.05, 0, 0], dt, True)
    assert est.n_hat == N0


@pytest.mark.parametrize('n0', [[0, 0, 0], [math.nan, 0, -1], [0, -1], 'up'])
def test_bad_initial_guess_is_refused(n0):
    with pytest.raises(NormalEstimateError, match='n0'):
        NormalEstimator(NormalConfig(), n0)


@pytest.mark.parametrize('kwargs, words', [
    ({'rate_limit': 0.0}, 'rate_limit must be finite and > 0'),
    ({'time_constant': math.inf}, 'time_constant'),
    ({'force_floor': -1.0}, 'force_floor'),
    ({'speed_floor': 'fast'}, 'speed_floor must be a number'),
    ({'velocity_fusion': 1.5}, 'velocity_fusion must be in [0, 1]'),
    ({'enabled': 1}, 'enabled must be a bool'),
    ({'friction_removal': 'yes'}, 'friction_removal must be a bool'),
])
def test_bad_settings_are_refused(kwargs, words):
    with pytest.raises(NormalConfigError) as exc:
        NormalConfig(**kwargs)
    assert words in str(exc.value)
    with pytest.raises(NormalConfigError, match='expected a NormalConfig'):
        NormalEstimator({'enabled': True}, N0)


# ---------------------------------------------------------------- as parameters
def test_parameters_build_the_group_and_check_the_rate_bound():
    model = RobotModel.from_urdf()
    p = build_params(model)
    assert p.normal == NormalConfig() and not p.normal.enabled  # the paper: n fixed
    p = build_params(model, {'n_estimation': True, 'n_rate_limit': 1.0, 'n_velocity_fusion': 0,
                             'n_friction_removal': False, 'n_speed_floor': 0.02})
    assert p.normal == NormalConfig(enabled=True, rate_limit=1.0, velocity_fusion=0.0,
                                    friction_removal=False, speed_floor=0.02)
    bound = normal_rate_bound(40.0, 0.1, 6000.0)
    assert bound == pytest.approx((math.sqrt(40.0 ** 2 + 20.0 * 400.0) - 40.0) / 10.0)
    assert 0.5 < bound / 10.0  # the default is an order of magnitude below it
    with pytest.raises(ParameterValidationError, match='n_rate_limit = 6 rad/s must be below'):
        build_params(model, {'n_estimation': True, 'n_rate_limit': 6.0})
    assert build_params(model, {'n_rate_limit': 6.0}).normal.rate_limit == 6.0  # off: unused
    for values, name in (({'n_velocity_fusion': 2.0}, 'n_velocity_fusion'),
                         ({'n_time_constant': 0.0}, 'n_time_constant'),
                         ({'n_estimation': 'yes'}, 'n_estimation')):
        with pytest.raises(ParameterValidationError, match=name):
            build_params(model, values)
