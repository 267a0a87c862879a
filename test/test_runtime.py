"""
ControllerRuntime (what the controller node does between messages).

Driven by arrays from the offline plant: input handling, safe mode, output order and a short closed
loop.

Closed loops go through the loop engine (engine.py, lockstep timing, one tick per plant
step), as scenario.py does: the plant starts at the paper's pose touching the surface
(k = 1700 N/m, normal -y); the wrist sensor reports the wrench in 'tool0'
(:func:`sensor_wrench_from_f_W`). No ROS.
"""
from __future__ import annotations

import math

from helpers.offline import DT, Loop
from hybrid_force_controller.core.config.params import build_params
from hybrid_force_controller.core.law.reference import SineReference
from hybrid_force_controller.core.offline.environment import sensor_wrench_from_f_W
from hybrid_force_controller.core.offline.scenario import PAPER_Q0
from hybrid_force_controller.core.runtime.controller_runtime import (ControllerRuntime,
                                                                     InputError, SAFE_DWELL_S)
from hybrid_force_controller.core.runtime.effort import SafeHold
import numpy as np
import pytest


Q0 = np.array(PAPER_Q0)


def feed_same(rts, model, q, qdot, F, t, names=None, frame='tool0'):
    names = list(model.joint_names) if names is None else names
    for rt in rts:
        rt.on_joint_state(names, q, qdot, t)
        rt.on_wrench(frame, F, t)


def started_pair(model, **overrides):
    """Two identical runtimes that have seen the same good inputs at t = 0."""
    params = build_params(model, overrides)
    rts = [ControllerRuntime(model, params), ControllerRuntime(model, params)]
    kin = model.kinematics(Q0, np.zeros(2))
    F = sensor_wrench_from_f_W(kin.R_W_ee, np.array([0.0, -1.0, 0.0]))
    feed_same(rts, model, Q0, np.array([0.05, -0.02]), F, 0.0)
    return rts, F


# ---------------------------------------------------------------- inputs
def test_tick_before_any_input_is_waiting(model):
    rt = ControllerRuntime(model, build_params(model, {}))
    out = rt.tick(0.0)
    assert out.mode == 'waiting' and out.tau is None
    rt.on_joint_state(list(model.joint_names), Q0, np.zeros(2), 0.001)
    out = rt.tick(0.001)  # still no wrench
    assert out.mode == 'waiting' and out.tau is None
    rt.on_wrench('tool0', [0.0, 0.0, 0.0], 0.002)
    out = rt.tick(0.002)  # no contact force yet: it approaches the surface
    assert out.mode == 'approach' and np.all(np.isfinite(out.tau))


def test_a_stale_input_before_the_first_effort_waits_and_is_no_safe_mode(model):
    """The first joint state 0.33 s after the last wrench: waiting, no effort, no safe mode."""
    rt = ControllerRuntime(model, build_params(model, {}))
    rt.on_wrench('tool0', [0.0, 0.0, 0.0], 0.0)
    rt.on_joint_state(list(model.joint_names), Q0, np.zeros(2), 0.333)
    out = rt.tick(0.333)
    assert out.mode == 'waiting' and out.tau is None and 'wrench older' in out.status
    assert rt.counters['safe_mode_entries'] == 0
    rt.on_wrench('tool0', [0.0, 0.0, 0.0], 0.334)
    out = rt.tick(0.334)  # both fresh: it starts as from WAITING
    assert out.mode == 'approach' and np.all(np.isfinite(out.tau))
    rt.tick(0.6)  # once it has commanded, stale inputs are safe mode as before
    assert rt.mode == 'safe' and rt.counters['safe_mode_entries'] == 1


def test_reordered_and_extra_joint_names(model):
    (a, b), F = started_pair(model)
    q, qdot = Q0 + [1e-4, -1e-4], np.array([0.1, -0.3])  # (a step the velocities explain)
    a.on_joint_state(['joint1', 'joint2'], q, qdot, 0.001)
    b.on_joint_state(['finger', 'joint2', 'joint1'], [0.33, q[1], q[0]],
                     [9.0, qdot[1], qdot[0]], 0.001)
    ta, tb = a.tick(0.001), b.tick(0.001)
    np.testing.assert_array_equal(ta.tau, tb.tau)
    np.testing.assert_array_equal(ta.x_W, tb.x_W)
    assert b.counters['joint_state_dropped'] == 0


def test_missing_controlled_joint_raises_and_counts(model):
    rt = ControllerRuntime(model, build_params(model, {}))
    with pytest.raises(InputError, match='joint2'):
        rt.on_joint_state(['joint1', 'other'], [0.6, 0.9], [0.0, 0.0], 0.0)
    assert rt.counters['joint_state_dropped'] == 1
    assert rt.tick(0.0).mode == 'waiting'  # nothing was stored


@pytest.mark.parametrize('bad_q,bad_qdot', [
    ([math.nan, 0.9], [0.0, 0.0]), ([0.6, 0.9], [0.0, math.inf])])
def test_nan_joint_state_dropped_last_good_kept(model, bad_q, bad_qdot):
    (a, b), F = started_pair(model)
    with pytest.raises(InputError):
        b.on_joint_state(list(model.joint_names), bad_q, bad_qdot, 0.0005)
    assert b.counters['joint_state_dropped'] == 1
    ta, tb = a.tick(0.001), b.tick(0.001)
    assert tb.mode == 'running'
    assert np.all(np.isfinite(tb.tau))
    np.testing.assert_array_equal(tb.tau, ta.tau)  # computed from the last good sample
    np.testing.assert_array_equal(tb.x_W, ta.x_W)


@pytest.mark.parametrize('bad', [[math.nan, 0.0, 0.0], [0.0, math.inf, 0.0], [1.0, 2.0]])
def test_bad_wrench_dropped_last_good_kept(model, bad):
    (a, b), F = started_pair(model)
    with pytest.raises(InputError):
        b.on_wrench('tool0', bad, 0.0005)
    assert b.counters['wrench_dropped'] == 1
    ta, tb = a.tick(0.001), b.tick(0.001)
    assert np.all(np.isfinite(tb.tau)) and np.all(np.isfinite(tb.f_W))
    np.testing.assert_array_equal(tb.tau, ta.tau)
    np.testing.assert_array_equal(tb.f_W, ta.f_W)


def test_unknown_wrench_frame_raises_naming_it(model):
    rt = ControllerRuntime(model, build_params(model, {}))
    with pytest.raises(InputError, match='camera_optical'):
        rt.on_wrench('camera_optical', [0.0, 1.0, 0.0], 0.0)
    assert rt.counters['wrench_dropped'] == 1


def test_wrench_in_base_link_is_not_rotated(model):
    params = build_params(model, {'force_filter_hz': 0.0})
    rt_base, rt_tool = ControllerRuntime(model, params), ControllerRuntime(model, params)
    F = np.array([0.3, 1.2, 0.0])
    for rt, frame in ((rt_base, 'base_link'), (rt_tool, 'tool0')):
        rt.on_joint_state(list(model.joint_names), Q0, np.zeros(2), 0.0)
        rt.on_wrench(frame, F, 0.0)
    ob, ot = rt_base.tick(0.0), rt_tool.tick(0.0)
    np.testing.assert_allclose(ob.f_W, -F, atol=1e-15)  # the force the tool exerts: -F
    R = model.kinematics(Q0, np.zeros(2)).R_W_ee
    assert not np.allclose(R, np.eye(3), atol=0.1)  # the tool frame is rotated here
    np.testing.assert_allclose(ot.f_W, -(R @ F), atol=1e-12)


def test_older_wrench_stamp_rejected(model):
    params = build_params(model, {'force_filter_hz': 0.0})
    rt = ControllerRuntime(model, params)
    rt.on_joint_state(list(model.joint_names), Q0, np.zeros(2), 1.0)
    rt.on_wrench('base_link', [0.0, 1.0, 0.0], 1.0)
    with pytest.raises(InputError, match='older'):
        rt.on_wrench('base_link', [0.0, 5.0, 0.0], 0.5)
    assert rt.counters['wrench_dropped'] == 1
    np.testing.assert_allclose(rt.tick(1.0).f_W, [0.0, -1.0, 0.0])  # the newer one is kept


# ---------------------------------------------------------------- output order
def test_tau_is_in_params_joint_order(model):
    fwd = build_params(model, {})
    rev = build_params(model, {'joints': ['joint2', 'joint1']})
    assert model.joint_names == ('joint1', 'joint2')
    a, b = ControllerRuntime(model, fwd), ControllerRuntime(model, rev)
    kin = model.kinematics(Q0, np.zeros(2))
    F = sensor_wrench_from_f_W(kin.R_W_ee, np.array([0.0, -1.0, 0.0]))
    for k in range(3):
        t = k * DT
        feed_same((a, b), model, Q0 + 1e-4 * k, np.array([0.1, -0.2]), F, t)
        ta, tb = a.tick(t), b.tick(t)
        assert abs(ta.tau[0] - ta.tau[1]) > 1.0  # the two joints' efforts differ
        np.testing.assert_array_equal(tb.tau, ta.tau[::-1])


# ---------------------------------------------------------------- closed loop and safe mode
def test_closed_loop_through_runtime_tracks_the_sine(model):
    loop = Loop(model)
    rt, law = loop.params.runtime, loop.params.law
    sine = SineReference(rt.ref_center, rt.ref_amplitude, rt.ref_omega)
    n = law.n
    e_tan, e_f = [], []
    for _ in range(int(round(6.0 / DT))):
        t = loop.t
        out, meas = loop.step()
        # the tool starts touching with 0 N: it approaches until the force is felt
        assert out.mode == ('approach' if t < 0.1 and out.mode == 'approach' else 'running')
        if t >= 5.0:
            d = meas.p_W - sine(t).x_d_W  # the runtime's sine starts at the first tick (t = 0)
            e_tan.append(np.linalg.norm(d - (d @ n) * n))
            e_f.append(float(meas.f_true_W @ n) - law.f_d)
    assert len(e_tan) >= 999
    assert math.sqrt(np.mean(np.square(e_tan))) <= 5e-4
    assert math.sqrt(np.mean(np.square(e_f))) <= 0.05
    assert loop.rt.counters['safe_mode_entries'] == 0
    assert loop.rt.counters['control_errors'] == 0
    assert loop.rt.counters['approach_entries'] == 1


@pytest.fixture(scope='module')
def outage(model):
    """
    Track until 3 s.

    Then no inputs for 150 ms (the plant keeps running under the runtime's effort), then inputs
    resume for 100 ms (safe mode ends SAFE_DWELL_S after they do).
    """
    loop = Loop(model)
    t_stop, t_resume = 3.0, 3.15
    rows = []
    while loop.t < t_resume + 0.1 - DT / 2:
        t = loop.t
        feed = not (t_stop - DT / 2 <= t < t_resume - DT / 2)
        xdot = model.kinematics(loop.meas.q, loop.meas.qdot).xdot
        out, _ = loop.step(feed=feed)
        rows.append((t, out.mode, out.tau, dict(loop.rt.counters), xdot))
    return loop, rows


def test_stale_inputs_enter_safe_mode_once(model, outage):
    loop, rows = outage
    safe = [r for r in rows if r[1] == 'safe']
    assert safe, 'no safe mode'
    # last input at 2.999 s; safe mode once the inputs are older than state_timeout = 0.1 s
    assert safe[0][0] == pytest.approx(2.999 + 0.1, abs=1.5 * DT)
    assert all(r[1] == 'running' for r in rows if 0.1 < r[0] < 3.099 - DT / 2)
    assert rows[-1][3]['safe_mode_entries'] == 1
    for _, _, tau, counters, _ in safe:
        assert np.all(np.isfinite(tau))
        assert np.all(np.abs(tau) <= loop.params.runtime.effort_limits)
        assert counters['safe_mode_entries'] == 1


def test_safe_mode_does_not_accelerate_the_arm(model, outage):
    """
    Safe mode is documented as gravity compensation + damping.

    With stale inputs the damping term must not turn into a push: the tool speed at the end of the
    outage is not larger than when the inputs stopped (+0.05 m/s: what the 1 N contact force, no
    longer compensated, gives the ~2 kg arm in 50 ms, with margin).
    """
    _, rows = outage
    speed = {round(r[0], 6): float(np.linalg.norm(r[4])) for r in rows}
    v_stop, v_end = speed[3.0], speed[3.15]
    assert v_stop == pytest.approx(0.1, abs=0.02)  # it was tracking the sine
    assert v_end <= v_stop + 0.05, f'tool speed {v_stop:.3f} -> {v_end:.3f} m/s in safe mode'


def test_resume_returns_to_running_without_torque_jump(model, outage):
    """
    Bound: 10 N m = 10 % of the effort limit (about 5 N at the 2 m tool).

    The laws differ at one state by the contact feed-forward J^T f (<= 2 N m at f_d = 1 N) and by
    k_d times the velocity mismatch built up in 50 ms of safe mode (a few N m); a restart that
    "does not jump" stays below that. In steady tracking one tick changes the effort by ~0.01 N m.
    """
    loop, rows = outage
    j = next(k for k, r in enumerate(rows) if r[1] == 'safe')
    i = next(k for k in range(j, len(rows)) if rows[k][1] == 'running')
    last_safe, first_run = rows[i - 1], rows[i]  # safe mode ends once the inputs held fresh
    assert last_safe[1] == 'safe'
    assert 3.15 + SAFE_DWELL_S - DT / 2 <= first_run[0] <= 3.15 + SAFE_DWELL_S + 3 * DT
    assert all(r[1] == 'running' for r in rows[i:])
    jump = np.abs(first_run[2] - last_safe[2]).max()
    assert jump < 10.0, f'effort jumps by {jump:.1f} N m: {last_safe[2]} -> {first_run[2]}'
    assert not np.any(np.abs(first_run[2]) >= loop.params.runtime.effort_limits)


T_FREEZE, FREEZE_S = 3.0, 1.2


@pytest.fixture(scope='module')
def frozen_wrench(model):
    """
    Freeze the wrench for 1.2 s at 3 s, then track for 1 s.

    Masses 0.65 and 1.35 kg (the law's residual is not zero); joint states keep coming.
    """
    held = {}

    def freeze(t, msg):
        q, qdot, F_S = msg
        if T_FREEZE <= t < T_FREEZE + FREEZE_S:
            F_S = held.setdefault('F_S', F_S)
        return q, qdot, F_S
    loop = Loop(model, plant_masses=[0.65, 1.35], input_hook=freeze)
    rows = []
    while loop.t < T_FREEZE + FREEZE_S + 1.0:
        out, meas = loop.step()
        rows.append((loop.t, out.mode, out.tau, float(loop.params.law.n @ meas.f_true_W),
                     meas.p_W, model.kinematics(meas.q, meas.qdot).xdot, loop.rt.run_time))
    return loop, rows


def test_safe_hold_is_continuous_stops_the_tool_and_keeps_contact(model, frozen_wrench):
    """
    A frozen wrench: safe mode after state_timeout (SafeHold, effort.py).

    At entry the effort is the last one out (no step); the tool brakes from the sine's 0.1 m/s
    to rest within 2 v0 SafeHold.T_STOP = 2 cm, the contact force stays within 0.1 N of
    f_d = 1 N (it rose 0.085 N), and after the fault the reference goes on from where it paused
    and the force is back within 0.05 N at once.
    """
    loop, rows = frozen_wrench
    i = next(k for k, r in enumerate(rows) if r[1] == 'safe')
    last_run, first_safe = rows[i - 1], rows[i]
    assert last_run[1] == 'running' and T_FREEZE < first_safe[0] < T_FREEZE + 0.15
    np.testing.assert_allclose(first_safe[2], last_run[2], atol=1e-9)
    safe = [r for r in rows if r[1] == 'safe']
    assert safe[-1][0] >= T_FREEZE + FREEZE_S - 0.01, 'left safe mode early'
    forces = [r[3] for r in safe]
    v0 = np.linalg.norm(safe[0][5])
    print(f'safe mode: force {min(forces):.3f}..{max(forces):.3f} N, speed {v0:.3f} -> '
          f'{np.linalg.norm(safe[-1][5]):.5f} m/s, '
          f'travel {np.linalg.norm(safe[-1][4] - safe[0][4]) * 1e3:.2f} mm')
    assert max(abs(f - 1.0) for f in forces) <= 0.1, (min(forces), max(forces))
    assert np.linalg.norm(safe[-1][5]) < 1e-3
    assert np.linalg.norm(safe[-1][4] - safe[0][4]) <= 2 * v0 * SafeHold.T_STOP + 2e-3
    j = next(k for k in range(i, len(rows)) if rows[k][1] == 'running')
    # the reference's time paused over the hold: it goes on from where it was (1 ms ticks)
    assert 0.0 < rows[j][6] - last_run[6] <= 3 * DT, (last_run[6], rows[j][6])
    after = [abs(r[3] - 1.0) for r in rows if r[0] >= T_FREEZE + FREEZE_S + 0.01]
    print(f'after: worst force error {max(after):.4f} N')
    assert max(after) <= 0.05


def test_safe_hold_reference_is_a_critically_damped_stop(model):
    """SafeHold.reference (effort.py): starts at (x0, v0), ends at rest 2 v0 T further on."""
    hold = SafeHold(model)
    hold.t0, hold.x0, hold.v0 = 5.0, np.array([1.0, 1.6]), np.array([-0.1, 0.02])
    T = SafeHold.T_STOP
    x, v = hold.reference(5.0)
    np.testing.assert_allclose(x, hold.x0)
    np.testing.assert_allclose(v, hold.v0)
    x, v = hold.reference(5.0 + 40 * T)
    np.testing.assert_allclose(x, hold.x0 + 2 * T * hold.v0, atol=1e-12)
    np.testing.assert_allclose(v, 0.0, atol=1e-12)
    for t in (5.03, 5.1, 5.25):  # xdot_h is the derivative of x_h
        h = 1e-6
        dx = (hold.reference(t + h)[0] - hold.reference(t - h)[0]) / (2 * h)
        np.testing.assert_allclose(dx, hold.reference(t)[1], atol=1e-8)
    # the deceleration starts at 0 (no jerk at entry) and peaks at v0 / (e T) at t0 + T
    a0 = (hold.reference(5.0 + 1e-6)[1] - hold.v0) / 1e-6
    assert np.abs(a0).max() < 1e-3
    a_T = (hold.reference(5.0 + T + 1e-6)[1] - hold.reference(5.0 + T - 1e-6)[1]) / 2e-6
    np.testing.assert_allclose(a_T, -hold.v0 / (math.e * T), rtol=1e-5)
