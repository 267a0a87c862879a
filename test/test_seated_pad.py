"""
A seated pad teaches the normal (normal_estimate.py (N7), orientation.py ``seated_axis``).

``orientation_mode`` moment with ``n_estimation``: a flat pad whose tilt moments are at their
target lies flat on the part, so its axis is the part's normal, at rest too, where the force
tells nothing closer than atan(mu). Offline, each relation:

* the estimator turns n_hat onto a seated pad's axis at once, within the rate limit, at rest;
  it learns mu_hat on while the seated pad slides; it refuses an axis opposite n_hat;
* ``seated_axis``: moment mode only, touching, with a measured moment, the centre of pressure
  (the tilt moment error over the force) within ``seat_offset`` of the pad's centre for
  ``SEAT_S``; a moment about the normal or at its target does not unseat it;
* the runtime: the Panda held still, told a normal 0.3 rad off its seated pad's axis, learns
  the axis without sliding (the stiffness fit waits while n_hat turns); the pad on its rim
  (5 N at 2.5 cm), free mode or ``n_seat_offset`` 0 leave n_hat at n, bit for bit;
* ``n_seat_offset``: a negative one is refused with its name.
"""
from __future__ import annotations

import math

from hybrid_force_controller.core.config.groups import NormalConfig, OrientationConfig
from hybrid_force_controller.core.config.params import build_params, ParameterValidationError
from hybrid_force_controller.core.law.normal_estimate import NormalEstimator
from hybrid_force_controller.core.law.orientation import SEAT_S, ToolOrientation
from hybrid_force_controller.core.model.rotations import angle_between
from hybrid_force_controller.core.offline.arm7 import panda_model, PANDA_Q0
from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime
import numpy as np
import pinocchio as pin
import pytest

DT = 1e-3
F_N = 5.0
RATE = 0.5  # n_rate_limit, rad/s
AXIS = np.array([0.0, math.sin(0.3), -math.cos(0.3)])  # the seated pad's axis: 0.3 rad off n0
N0 = (0.0, 0.0, -1.0)


def _estimator(**kwargs) -> NormalEstimator:
    return NormalEstimator(NormalConfig(enabled=True, rate_limit=RATE, **kwargs), N0)


def test_a_seated_pads_axis_turns_n_hat_at_rest_at_the_rate_limit():
    est, f = _estimator(), (F_N * AXIS).tolist()
    angles = [angle_between(np.array(est.n_hat), AXIS)]
    for _ in range(int(0.7 / DT)):
        assert est.update(f, [0.0, 0.0, 0.0], DT, True, AXIS.tolist())
        assert est.state == 'seated'
        angles.append(angle_between(np.array(est.n_hat), AXIS))
    steps = -np.diff(angles)
    assert steps.max() <= RATE * DT * (1 + 1e-9)  # (N6)'s rate limit holds
    assert steps[:500].min() >= RATE * DT * (1 - 1e-6)  # a_n = 1: at the limit until there
    assert angles[-1] < 1e-12 and est.mu_hat == 0.0  # on the axis; mu_hat held at rest
    assert not est.update(f, [0.0, 0.0, 0.0], DT, True)  # unseated at rest: held again
    assert est.state == 'at_rest'


def test_a_seated_pad_that_slides_learns_mu_and_keeps_n_hat_on_its_axis():
    est, mu = _estimator(), 0.3
    u = np.array([1.0, 0.0, 0.0])  # tangent: across AXIS
    f = (F_N * AXIS + mu * F_N * u).tolist()  # (N1): friction along the velocity
    for _ in range(int(4.0 / DT)):
        est.update(f, (0.05 * u).tolist(), DT, True, AXIS.tolist())
    assert angle_between(np.array(est.n_hat), AXIS) < 1e-12
    assert est.mu_hat == pytest.approx(mu, abs=1e-3)


def test_an_axis_opposite_n_hat_is_refused():
    est = _estimator()
    assert not est.update([0.0, 0.0, -F_N], [0.0, 0.0, 0.0], DT, True, [0.0, 0.0, 1.0])
    assert est.state == 'implausible' and est.n_hat == N0


def _pad(**kwargs) -> ToolOrientation:
    return ToolOrientation(OrientationConfig(mode=kwargs.pop('mode', 'moment'), **kwargs))


def _seated(pad, m_W, touching=True, offset=0.01, steps=int(round(SEAT_S / DT))):
    """Call seated_axis ``steps`` times (the tool axis z, the normal and force along it)."""
    n, out = np.array([0.0, 0.0, 1.0]), None
    for _ in range(steps):
        out = pad.seated_axis(np.eye(3), n, F_N * n, None if m_W is None else np.array(m_W),
                              DT, touching, offset)
    return out


def test_seated_axis_needs_the_dwell_then_gives_the_tool_axis():
    pad = _pad()
    assert _seated(pad, [0.0, 0.0, 0.0], steps=int(round(SEAT_S / DT)) - 1) is None
    np.testing.assert_array_equal(_seated(pad, [0.0, 0.0, 0.0], steps=1), [0.0, 0.0, 1.0])


@pytest.mark.parametrize('m_W, seated', [
    ([0.009 * F_N, 0.0, 0.0], True),  # the centre of pressure 9 mm off: within 10 mm
    ([0.0, 0.011 * F_N, 0.0], False),  # 11 mm: not seated
    ([0.125, 0.0, 0.0], False),  # the pad on its rim: 5 N at 2.5 cm
    ([0.0, 0.0, 1.0], True),  # a moment about the normal tilts nothing
])
def test_seated_axis_reads_the_centre_of_pressure(m_W, seated):
    assert (_seated(_pad(), m_W) is not None) == seated


def test_seated_axis_measures_the_moment_from_its_target():
    pad = _pad()
    pad.set_moment_target(np.array([0.1, 0.0, 0.0]))
    assert _seated(pad, [0.1, 0.0, 0.0]) is not None
    assert _seated(_pad(), [0.1, 0.0, 0.0]) is None  # the same moment, target 0: on its rim


@pytest.mark.parametrize('case', ['not touching', 'no moment yet', 'normal mode', 'offset 0'])
def test_seated_axis_is_none_outside_its_conditions(case):
    pad = _pad(mode='normal' if case == 'normal mode' else 'moment')
    assert _seated(pad, None if case == 'no moment yet' else [0.0, 0.0, 0.0],
                   touching=case != 'not touching',
                   offset=0.0 if case == 'offset 0' else 0.01) is None


def test_leaving_the_seat_restarts_the_dwell():
    pad = _pad()
    assert _seated(pad, [0.0, 0.0, 0.0]) is not None
    assert _seated(pad, [0.0, 0.0, 0.0], touching=False, steps=1) is None
    assert _seated(pad, [0.0, 0.0, 0.0], steps=int(round(SEAT_S / DT)) - 1) is None


@pytest.fixture(scope='module')
def panda():
    return panda_model()


def _held_still(panda, overrides: dict, lever_m: float = 0.0, seconds: float = 1.5):
    """
    Hold the Panda still, its pad pressing 5 N along its own axis, told n 0.3 rad off.

    Seated: no tilt moment; ``lever_m`` > 0: on its rim, the centre of pressure that far off.

    Return the runtime, its normal in use at the end and whether the stiffness fit was still
    while n_hat turned.
    """
    q = np.array(PANDA_Q0)
    R = panda.kinematics(q, np.zeros(7)).R_W_ee
    a_W = R[:, 2]  # the tool axis (tool_axis z), into the part
    n_told = pin.exp3(0.3 * np.cross(a_W, [1.0, 0.0, 0.0]) / np.linalg.norm(
        np.cross(a_W, [1.0, 0.0, 0.0]))).dot(a_W)
    f_W = F_N * a_W  # the force the tool exerts on the part
    m_W = np.cross(lever_m * R[:, 0], f_W)  # its moment about the pad's centre
    rt = ControllerRuntime(panda, build_params(panda, {
        'n': n_told.tolist(), 'n_estimation': True, 'f_d': F_N, **overrides}))
    names, frame = list(panda.joint_names), panda.end_effector_link
    still_while_turning, rng = False, np.random.default_rng(3)
    for k in range(1, int(seconds / DT) + 1):
        t = k * DT
        rt.on_joint_state(names, q, np.zeros(7), t)
        F_S, T_S = -R.T @ f_W, -R.T @ m_W  # what the sensor reads, with its noise (a reading
        rt.on_wrench(frame, F_S + rng.normal(0.0, 0.01, 3), t,  # repeated exactly is frozen)
                     torque=T_S + rng.normal(0.0, 1e-4, 3))
        n_before = rt._normal.n
        rt.tick(t)
        still_while_turning |= rt._normal.still and rt._normal.n != n_before
    return rt, np.array(rt._normal.n), a_W, n_told, still_while_turning


def test_the_runtime_learns_the_normal_from_a_seated_pad_without_sliding(panda):
    rt, n, a_W, n_told, still_while_turning = _held_still(panda, {'orientation_mode': 'moment'})
    assert angle_between(n, n_told) > 0.29  # it moved the whole way ...
    assert angle_between(n, a_W) < 1e-9  # ... onto the pad's axis
    assert rt._normal.estimator.state == 'seated' and rt._normal.still
    assert not still_while_turning  # the stiffness fit waited while n_hat turned (M3)


@pytest.mark.parametrize('overrides, lever_m', [
    ({'orientation_mode': 'moment'}, 0.025),  # on its rim
    ({'orientation_mode': 'moment', 'n_seat_offset': 0.0}, 0.0),  # off
    ({'orientation_mode': 'free'}, 0.0),
])
def test_without_a_seated_pad_n_hat_stays_at_rest(panda, overrides, lever_m):
    rt, n, _, n_told, _ = _held_still(panda, overrides, lever_m, seconds=0.5)
    assert n.tolist() == rt._normal.n_p_W.tolist()  # held, bit for bit: the force is not used
    assert angle_between(n, n_told) < 1e-12  # (the told n, as the parameters normalised it)
    assert rt._normal.estimator.state == 'at_rest'


def test_a_negative_seat_offset_is_refused_with_its_name(panda):
    with pytest.raises(ParameterValidationError, match='n_seat_offset'):
        build_params(panda, {'n_seat_offset': -0.01})
    assert build_params(panda, {'n_seat_offset': 0}).normal.seat_offset == 0.0
