"""
Fault injection over real DDS: bad inputs and process faults against the real nodes.

One ``sim`` process (lockstep, owns /clock) and one controller process (``use_sim_time``)
run for the whole module; this process sits between them (see ``helpers.fault_rig``): it
forwards the sim's joint states and wrench to the controller through fault hooks, injects
bad messages, sets parameters, kills and restarts processes. Around every case the rig
checks (1) the controller process is alive, (2) every effort it published was finite and
(3) within the effort limits (100 N m, the bundled URDF) and, when set, within
``max_effort_rate`` per tick. Each case then checks (4) what was reported on /diagnostics
(counters, mode, contact, and the text of the last input fault, never log lines) and (5)
that tracking returns: the true normal force within 0.05 N of f_d for 0.3 s of sim time
and a /diagnostics status from that window saying 'running', in contact.

Lockstep makes the loop independent of the machine's load; every bound is on sim time.
Seeds are fixed (the sim's noise is off; nothing here is random). The rig and its fixtures are
conftest.py's (``fault_rig``, ``healthy``: a case that failed is followed by a reset, never
hidden); bad joint states, wrenches and stamps are test_fault_inputs.py's.
"""
import math
import signal

from helpers.fault_cases import (APPROACH_SPEED, assert_unaffected, COMMAND_TIMEOUT, counters,
                                 delta, F_D, LAMBDA1, largest_step, MODEL, N_W, sensor_force,
                                 tool_motion, wrench_copy)
from helpers.fault_rig import Rig, stamp_s
import numpy as np
import pytest


# ----------------------------------------------------------------------------- parameters
REJECTED = [
    ('wrong type', {'lambda1': 'fast'}, 'must be a number'),
    ('out of range', {'f_d': 5000.0}, 'f_d'),
    ('unstable by eq. (29)', {'lambda1': 10.0}, '1200'),
    ('bad n', {'n': [0.0, 0.0, 1.0]}, 'leaves the task space'),
    ('bad gamma', {'gamma': [70.0, -1.0]}, 'positive definite'),
]


@pytest.mark.parametrize('what, values, reason', REJECTED, ids=[r[0] for r in REJECTED])
def test_rejected_parameter_set_changes_nothing(healthy, what, values, reason):
    rig = healthy
    with rig.case():
        names = list(values)
        old = rig.get_params(rig.params, *names)
        before = rig.last_diag()
        t0 = rig.now
        (result,) = rig.set_params(rig.params, **values)
        assert not result.successful, what
        assert reason in result.reason, result.reason
        assert rig.get_params(rig.params, *names) == old
        after = counters(rig, t0 + 0.2, what)
        assert after['mode'] == 'running' and delta(after, before, 'safe_mode_entries') == 0
        assert_unaffected(rig, t0, what)


def test_good_multi_value_set_applies_atomically(healthy):
    """
    lambda2 = 0.15 alone breaks eq. (29) with lambda1 = 40 (1600 <= 1800).

    With lambda1 = 50 in the same set it holds (2500 > 1800): the set is validated and applied as
    one.
    """
    rig = healthy
    with rig.case():
        alone = rig.set_params(rig.params, lambda2=0.15)[0]
        assert not alone.successful and '1800' in alone.reason, alone.reason
        result = rig.set_atomically(rig.params, f_d=1.5, lambda1=50.0, lambda2=0.15)
        assert result.successful, result.reason
        assert rig.get_params(rig.params, 'f_d', 'lambda1', 'lambda2') == [1.5, 50.0, 0.15]
        with rig.proxy.cv:
            rig.proxy.f_d, rig.proxy.t_force_bad = 1.5, rig.now
        rig.wait_tracking(3.0, 'f_d = 1.5 N')
        result = rig.set_atomically(rig.params, f_d=F_D, lambda1=LAMBDA1, lambda2=0.1)
        assert result.successful, result.reason
        with rig.proxy.cv:
            rig.proxy.f_d, rig.proxy.t_force_bad = F_D, rig.now
    rig.wait_tracking(3.0, 'f_d back to 1 N')


def test_sim_surface_parameters_are_validated(healthy):
    rig = healthy
    with rig.case():
        old = rig.get_params(rig.sim_params, 'stiffness', 'surface_point', 'surface_normal')
        t0 = rig.now
        for values, reason in (({'stiffness': -1.0}, 'out of range'),
                               ({'stiffness': 'hard'}, 'must be a number'),
                               ({'surface_normal': [0.0, 0.0, 0.0]}, 'normal'),
                               ({'surface_point': [1.0, 2.0]}, 'point')):
            (result,) = rig.set_params(rig.sim_params, **values)
            assert not result.successful and reason in result.reason, (values, result.reason)
        assert rig.get_params(rig.sim_params, 'stiffness', 'surface_point',
                              'surface_normal') == old
        rig.run_for(0.1)
        assert_unaffected(rig, t0, 'rejected surface parameters')
        assert rig.set_params(rig.sim_params, stiffness=3000.0)[0].successful
        rig.wait_tracking(3.0, 'stiffer surface (3000 N/m)')
        assert rig.set_params(rig.sim_params, stiffness=1700.0)[0].successful
    rig.wait_tracking(3.0, 'surface back to 1700 N/m')


# ----------------------------------------------------------------------------- stale inputs
def stale_case(rig: Rig, what: str, drop_js: bool, jump_bound: float) -> None:
    """
    Stop one input for 0.2 s of sim time (> state_timeout = 0.1 s) and resume it.

    Without joint states nothing can hold this arm for long (link 2 stands up: an inverted
    pendulum with a ~0.3 s time constant, and safe mode has no velocity to damp), so the
    outage is kept to 0.1 s of safe mode.
    """
    def drop(msg):
        return []
    with rig.case():
        before = rig.last_diag()
        t0, t1 = rig.fault(0.2, js=drop if drop_js else None,
                           wrench=None if drop_js else drop)
        # the first status back in 'running', within 1 s of sim time of the input's return
        after = rig.diag_after(t1 + 0.02, what, lambda d: d['mode'] == 'running', within=1.0)
        assert delta(after, before, 'safe_mode_entries') == 1, (before, after)
        assert after['mode'] == 'running', after
        name = 'joint states' if drop_js else 'wrench'
        assert f'{name} older than state_timeout' in after['last_safe_reason'], after
        rig.wait_tracking(3.0, f'{what}: recovery')
        step = largest_step(rig, t1 - 0.01, t1 + 0.1)
        assert step <= jump_bound, f'{what}: effort jump {step:.2f} N m on recovery'


def test_stale_joint_states_safe_mode_and_recovery(healthy):
    """
    Bound on the effort jump when the loop takes over again.

    The reference restarts from the arm's position and velocity, so e = 0 and the first running
    effort differs from the safe hold g_hat + J^T f_hold (no damping: the velocity is stale) only
    by J^T (f - f_hold) + k_d J^T (normal force-loop term) + M qddot_r + C qdot_r. With |J^T| <= 2
    m, |f - f_hold| <= 0.2 N, c lambda1 |df| k_d <= 0.3 N and |qddot_r| from the reference's
    acceleration (<= 0.1 m/s^2 at 2.2 kg) that is <= 2 (0.2 + 0.3 + 0.3) ~ 1.6 N m: 3 N m (3 % of
    the limit). Offline over 13 phases of the sine: <= 0.52 N m.
    """
    stale_case(healthy, 'stale joint states', drop_js=True, jump_bound=3.0)


def test_stale_wrench_safe_mode_with_rate_limit(healthy):
    """
    The same with max_effort_rate = 5 N m per tick.

    The limit holds across entering and leaving safe mode (the effort monitor checks every tick).
    """
    rig = healthy
    assert rig.set_params(rig.params, max_effort_rate=5.0)[0].successful
    rig.set_limits(rate=5.0)
    try:
        stale_case(rig, 'stale wrench', drop_js=False, jump_bound=5.0)
    finally:
        assert rig.set_params(rig.params, max_effort_rate=0.0)[0].successful
        rig.set_limits(rate=0.0)


# ----------------------------------------------------------------------------- sim commands
def test_sim_rejects_bad_commands_holds_then_zeroes(healthy):
    """The controller is paused (SIGSTOP) so that this process alone commands the sim."""
    rig = healthy
    with rig.case() as info, rig.quick_watchdog():
        rig.controller.signal(signal.SIGSTOP)
        rig.expect_alive['controller'] = False
        try:
            t_stop = rig.now
            rig.run_for(0.002)  # two watchdog steps: the last controller command is held
            # the effort of those steps, not of the newest state: the sim steps on (every 0.2 s
            # of wall time) and zeroes it after COMMAND_TIMEOUT, before a slow reader looks (s47c)
            held = [m for t, m in list(rig.proxy.js_log) if t_stop < t <= t_stop + 0.002]
            last = np.array((held[-1] if held else rig.proxy.js_raw).effort)
            # (this process may read the command after the state the sim stepped with it)
            rig.wait(lambda: any(np.array_equal(last, c) for _, c in rig.proxy.cmds[-3:]),
                     'the held effort among the last commands of the controller')
            valid = last + np.array([0.5, -0.5])
            rig.proxy.inject_command(valid.tolist())
            rig.wait(lambda: np.allclose(rig.proxy.js_raw.effort, valid),
                     'a step with the valid command')
            t_valid = stamp_s(rig.proxy.js_raw.header.stamp) - 0.001  # sim time it came at
            bad = {'rejected command [nan, 0.0]': [math.nan, 0.0],
                   'rejected command [0.0, inf]': [0.0, math.inf],
                   'rejected command [1.0, 2.0, 3.0]': [1.0, 2.0, 3.0],
                   'rejected command []': []}
            while bad:  # the sim's warning is throttled (1 s): send until each one is logged
                rig.proxy.inject_command(next(iter(bad.values())))
                t = rig.run_for(0.001)  # a watchdog step, not a step on the bad command
                if t < t_valid + COMMAND_TIMEOUT:
                    np.testing.assert_allclose(rig.proxy.js_raw.effort, valid)  # held
                log = rig.sim_log(info)
                bad = {text: data for text, data in bad.items() if text not in log}
                assert rig.now < t_valid + 0.5, f'never logged: {list(bad)}'
            rig.wait(lambda: rig.proxy.now > t_valid + COMMAND_TIMEOUT + 0.0025,
                     'command_timeout')
            np.testing.assert_array_equal(rig.proxy.js_raw.effort, [0.0, 0.0])
            assert 'no valid command within command_timeout: zero effort' in rig.sim_log(info)
            assert rig.sim.alive and rig.now > t_stop
        finally:
            rig.controller.signal(signal.SIGCONT)
            rig.expect_alive['controller'] = True
        rig.wait_tracking(3.0, 'controller resumed')


# ----------------------------------------------------------------------------- contact loss
# ----------------------------------------------------------------------------- force spikes
def with_rate_limit(rig: Rig, rate: float):
    assert rig.set_params(rig.params, max_effort_rate=rate)[0].successful
    rig.set_limits(rate=rate)


def test_force_spike_of_1e4_newton_is_dropped(healthy):
    """
    One wrench sample of 1e4 N (along the normal).

    Implausible (above wrench_limit), so it is dropped and counted, named on /diagnostics, and
    tracking is not disturbed.
    """
    rig = healthy
    with rig.case():
        before = rig.last_diag()
        sent = []

        def spike(msg):
            if sent:
                return [msg]
            sent.append(msg)
            return [wrench_copy(msg, force=sensor_force(rig, 1e4))]
        t0 = rig.now
        rig.proxy.wrench_hook = spike
        rig.wait(lambda: bool(sent), 'the spike')
        rig.proxy.wrench_hook = None
        after = counters(rig, t0, 'spike')
        assert delta(after, before, 'wrench_implausible') == 1, (before, after)
        assert 'wrench_limit' in after['last_input_fault']
        assert delta(after, before, 'safe_mode_entries') == 0
        rig.run_for(0.2)
        assert_unaffected(rig, t0, '1e4 N spike')


def test_saturated_force_sensor_holds_in_safe_mode_and_recovers(healthy):
    """
    The sensor reads 1e4 N for 0.3 s (a saturated sensor looks the same).

    Every reading is dropped, the wrench ages past state_timeout and the arm holds in safe mode;
    when the readings are plausible again, tracking returns by itself.
    """
    rig = healthy
    with rig.case():
        before = rig.last_diag()
        t0, t1 = rig.fault(0.3, wrench=lambda m: [wrench_copy(m, force=sensor_force(rig, 1e4))])
        after = counters(rig, t1, 'saturated sensor')
        assert delta(after, before, 'wrench_implausible') >= 250, (before, after)
        assert delta(after, before, 'safe_mode_entries') == 1, (before, after)
        assert 'wrench older than state_timeout' in after['last_safe_reason'], after
        rig.wait_tracking(3.0, 'after the saturated sensor')


# ----------------------------------------------------------------------------- restarts
def test_sim_restart_while_controller_runs(healthy):
    """
    Kill the sim and start it again.

    /clock jumps back to zero; the controller restarts its clock (counted), waits for fresh inputs
    and tracks again, with no manual step.
    """
    rig = healthy
    with rig.case():
        before = rig.last_diag()
        jumps = rig.proxy.clock_jumps
        rig.expect_alive['sim'] = False
        rig.sim.kill()
        rig.sim.start()
        rig.expect_alive['sim'] = True
        rig.wait(lambda: rig.proxy.clock_jumps > jumps, 'the restarted sim')
        after = rig.diag_after(0.0, 'after the clock jump',
                               lambda d: d['mode'] == 'running', within=5.0)
        assert delta(after, before, 'clock_restarts') == 1, (before, after)
        rig.wait_tracking(5.0, 'after the sim restart')


def test_controller_restart_while_sim_runs(healthy):
    """
    Kill the controller.

    The sim keeps stepping on its watchdog (held, then zero effort); start the controller again: it
    tracks again with no manual step.
    """
    rig = healthy
    with rig.case(), rig.quick_watchdog():
        rig.expect_alive['controller'] = False
        rig.controller.kill()
        t_kill = rig.now
        rig.run_for(0.003)  # the sim keeps running without the controller
        assert rig.now > t_kill
        rig.controller.start()
        rig.expect_alive['controller'] = True
        d = rig.diag_after(t_kill, 'the restarted controller',
                           lambda d: d['mode'] == 'running' and d['ticks'] < 5000, within=5.0)
        assert d['ticks'] < 5000 and d['clock_restarts'] == 0, d  # a fresh process
        rig.wait_tracking(5.0, 'after the controller restart')


# ----------------------------------------------------------------------------- contact loss
def test_surface_drop_is_regained_by_the_approach(healthy):
    """
    The surface drops 3 cm (the sim's surface_point).

    Out of contact the controller approaches at approach_speed (mode 'approach'; the force integral
    stays frozen, so no faster) and regains the surface within 1.5 s of sim time, with an impact
    below 5 f_d. Last in the module: the rig is reset afterwards (the surface stays lower).
    """
    rig = healthy
    try:
        with rig.case():
            before = rig.last_diag()
            q0 = np.array([0.657, 0.913])  # config/params.yaml: the surface runs through
            p0 = MODEL.kinematics(q0, np.zeros(2)).p_W  # the tool's start position
            t_off = rig.now
            lower = (p0 + 0.03 * N_W).tolist()
            assert rig.set_params(rig.sim_params, surface_point=lower)[0].successful
            # the 1 Hz status may fall outside the ~1.2 s approach: the first one after the
            # drop that is out of contact, or that counts the approach, whichever comes first
            lost = rig.diag_after(t_off, 'contact lost', lambda d: d['in_contact'] is False or (
                delta(d, before, 'approach_entries') == 1), within=3.0)
            if lost['in_contact'] is False:  # a status during the approach reports it
                assert lost['mode'] == 'approach' and lost['level'] == 1, lost
            assert delta(lost, before, 'approach_entries') == 1, lost
            # from now on: a status stamped between t_off and the loss still reads in contact
            back = rig.diag_after(rig.now, 'contact back', lambda d: d['in_contact'] is True,
                                  within=3.0)
            assert back['mode'] == 'running'
            assert delta(back, before, 'approach_entries') == 1
            assert delta(back, before, 'safe_mode_entries') == 0
            ts, ps, vs = tool_motion(rig, t_off + 0.3, t_off + 1.0)
            v_n = vs @ N_W
            assert v_n.mean() == pytest.approx(APPROACH_SPEED, rel=0.2)
            assert v_n.max() <= 1.2 * APPROACH_SPEED, f'approach at {v_n.max():.4f} m/s'
            peak = max(f for t, f in rig.proxy.force_log if t >= t_off)
            assert peak <= 5.0 * F_D, f'impact of {peak:.2f} N'
            t_back = min(t for t, f in rig.proxy.force_log if t >= t_off + 0.3 and f > 0.1)
            assert t_back - t_off <= 1.5, f'contact back after {t_back - t_off:.2f} s'
            rig.wait_tracking(5.0, 'on the lower surface')
    finally:
        rig.reset()
