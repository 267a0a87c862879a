"""
The desired force's ramp (law/force_reference.py, fed forward in eq. 11) and the sensor tare.

Offline: the runtime on the paper's plant through the loop engine (helpers.offline.Loop), and the
pure pieces alone. The tare's DDS side (the ~/tare service) is in test_task_interface.py.
"""
from __future__ import annotations

from helpers.offline import Loop
from hybrid_force_controller.core.law.force_reference import ForceRamp
from hybrid_force_controller.core.offline.environment import sensor_wrench_from_f_W
from hybrid_force_controller.core.runtime.tare import STILL_QDOT, Tare
import numpy as np
import pytest


def test_the_ramp_moves_at_its_rate_and_stops_on_the_target():
    ramp = ForceRamp(1.0, 10.0)
    ramp.configure(2.0, 10.0)
    values = [ramp.step(0.01) for _ in range(12)]
    assert values[:10] == pytest.approx(np.linspace(1.1, 2.0, 10), abs=1e-12)
    assert values[10:] == [2.0, 2.0] and ramp.fdot == 0.0
    ramp.configure(1.5, 10.0)
    assert ramp.step(0.01) == pytest.approx(1.9) and ramp.fdot == -10.0
    assert ramp.step(0.0) == pytest.approx(1.9) and ramp.fdot == -10.0  # no new state: same rate
    ramp.configure(3.0, 0.0)  # rate 0: a step
    assert ramp.value == 3.0 and ramp.fdot == 0.0


def test_a_ramped_f_d_is_fed_forward_in_r_and_rdot(model):  # noqa: F811
    """Eq. (11) with fdot_d: r_n gains c fdot_d and rdot_n gains lambda1 c fdot_d."""
    loop = Loop(model)
    ctrl = loop.rt.ctrl
    ctrl.h = 0.01
    r0, rdot0 = ctrl.force_loop_r_n(1.3)
    ctrl.set_force_setpoint(ctrl.f_d, 12.0)
    r1, rdot1 = ctrl.force_loop_r_n(1.3)
    c, l1 = 1.0 / ctrl.k_s, ctrl.gains.lambda1
    assert r1 - r0 == pytest.approx(c * 12.0, rel=1e-12)
    assert rdot1 - rdot0 == pytest.approx(l1 * c * 12.0, rel=1e-12)


def _f_d_change(model, rate):  # noqa: F811
    """f_d 1 -> 3 N after 3 s of the paper's run; the desired and the true normal force after."""
    loop = Loop(model, f_d_rate=rate)
    for _ in range(3000):
        loop.step()
    loop.rt.set_params(loop.rt.validate({'f_d_rate': rate, 'f_d': 3.0}))
    f_d, f_n = [], []
    for _ in range(2000):
        out, meas = loop.step()
        f_d.append(float(out.f_d_W @ loop.params.law.n))
        f_n.append(float(meas.f_true_W @ loop.params.law.n))
    return np.array(f_d), np.array(f_n)


def test_a_new_f_d_ramps_and_the_force_follows_without_the_step_overshoot(model):  # noqa: F811
    """Measured: a 2 N step peaks at 4.42 N, the 10 N/s ramp at 3.07 N (settled: 3.000 N)."""
    f_d, f_n = _f_d_change(model, 10.0)
    assert f_d[99] == pytest.approx(2.0, abs=0.02) and f_d[199] == pytest.approx(3.0, abs=1e-9)
    assert np.all(np.diff(f_d) <= 10.0 * 1e-3 + 1e-12) and np.all(np.diff(f_d) >= 0.0)
    assert f_n.max() <= 3.1 and abs(f_n[-1] - 3.0) < 0.01
    f_d_step, f_n_step = _f_d_change(model, 0.0)  # negative control: the step
    assert f_d_step[0] == 3.0 and f_n_step.max() > 4.0


def test_the_tare_is_the_mean_raw_reading_less_the_tool_weight():
    tare = Tare(0.01, weight_S=np.array([0.0, 0.0, -0.98]))
    rng = np.random.default_rng(3)
    for k in range(12):
        fx, fy, fz = np.array([2.0, -1.0, 0.5]) + rng.normal(0.0, 0.01, 3)
        tare.add(fx, fy, fz - 0.98, k * 1e-3)
    assert tare.state == 'done' and tare.samples == 11  # 10 ms of stamps
    np.testing.assert_allclose(tare.offset, [2.0, -1.0, 0.5], atol=0.01)
    tare.add(100.0, 100.0, 100.0, 0.02)  # a finished tare takes nothing more
    assert tare.samples == 11


def test_the_runtime_tares_a_still_arm_and_subtracts_the_offset(model):  # noqa: F811
    bias = np.array([0.8, -2.5, 0.3])
    loop = Loop(model)
    for _ in range(5):
        loop.step()
    # lift the tool off the surface: no contact, the arm held still by its brakes (no ticks)
    m, tare = loop.meas, Tare(0.02)
    for k in range(30):
        t = loop.t + k * 1e-3
        loop.rt.on_joint_state(list(model.joint_names), m.q, np.zeros(model.n), t)
        if k == 0:
            loop.rt.start_tare(tare)
        loop.rt.on_wrench('tool0', bias, t)
    assert tare.state == 'done', tare.reason
    np.testing.assert_allclose(tare.offset, bias, atol=1e-12)
    params = loop.rt.validate({'wrench_offset': tare.offset.tolist()})
    loop.rt.set_params(params)
    for k in range(50):
        loop.rt.on_wrench('tool0', bias + np.array([0.0, 1.0, 0.0]), loop.t + 0.1 + k * 1e-3)
        f_W = loop.rt._in.filtered_force()  # the bias is gone; 1 N along the sensor's y remains
    assert np.linalg.norm(f_W) == pytest.approx(1.0, abs=0.05)


def test_a_tare_is_refused_while_the_arm_moves_or_in_contact(model):  # noqa: F811
    loop = Loop(model)
    for _ in range(300):  # running the sine, pressing 1 N
        loop.step()
    touching = Tare(0.1)
    loop.rt.start_tare(touching)
    assert touching.state == 'aborted' and 'in contact' in touching.reason
    m = loop.meas
    moving = Tare(0.1)
    loop.rt._contact.active = False  # as after lifting off
    loop.rt.on_joint_state(list(model.joint_names), m.q, np.full(model.n, 3 * STILL_QDOT),
                           loop.t + 1e-3)
    loop.rt.start_tare(moving)
    loop.rt.on_wrench('tool0', sensor_wrench_from_f_W(m.R_W_ee, m.f_W), loop.t + 1e-3)
    assert moving.state == 'aborted' and 'moving' in moving.reason


def test_a_tare_before_any_input_waits_for_the_inputs(model):  # noqa: F811
    """A tare asked right after configure starts with the first joint state and wrench."""
    loop = Loop(model)
    tare = Tare(0.005)
    loop.rt.start_tare(tare)
    loop.rt.on_wrench('tool0', [0.0, 2.0, 0.0], 0.0)  # no joint state yet: not taken
    assert tare.running and tare.samples == 0
    m, names = loop.meas, list(model.joint_names)
    for k in range(1, 8):
        loop.rt.on_joint_state(names, m.q, np.zeros(model.n), k * 1e-3)
        loop.rt.on_wrench('tool0', [0.0, 2.0, 0.0], k * 1e-3)
    assert tare.state == 'done' and tare.samples == 6
    np.testing.assert_allclose(tare.offset, [0.0, 2.0, 0.0])


def test_a_tare_under_way_stops_when_the_arm_moves(model):  # noqa: F811
    loop = Loop(model)
    loop.step()
    loop.rt._contact.active = False
    m, names = loop.meas, list(model.joint_names)
    tare = Tare(1.0)
    loop.rt.on_joint_state(names, m.q, np.zeros(model.n), loop.t + 1e-3)
    loop.rt.start_tare(tare)
    loop.rt.on_wrench('tool0', sensor_wrench_from_f_W(m.R_W_ee, m.f_W), loop.t + 1e-3)
    loop.rt.on_joint_state(names, m.q, np.full(model.n, 0.1), loop.t + 2e-3)
    loop.rt.on_wrench('tool0', sensor_wrench_from_f_W(m.R_W_ee, m.f_W), loop.t + 2e-3)
    assert tare.state == 'aborted' and 'moving' in tare.reason and tare.offset is None
