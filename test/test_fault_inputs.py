"""
Input faults over real DDS: bad joint states and wrenches, and their stamps, against the nodes.

The lockstep fault-injection rig (``helpers.fault_rig``, conftest.py's ``fault_rig``): this
process forwards the sim's joint states and wrench to the controller and corrupts some of them
(NaN/Inf, missing or extra joints, wrong lengths, unknown frames, stamps out of order, copies).
Every bad message is dropped, counted and named on /diagnostics (the last one's reason), and
tracking is not disturbed at all; good variants (reordered joints, a wrench in base_link,
duplicates) change nothing. Around every case the rig checks that the controller lives and
every effort it published was finite and within the limits. Lockstep: every bound is on sim
time. Parameters, stale inputs, the sim's commands, restarts and contact loss:
test_fault_injection.py.
"""
import math

from helpers.fault_cases import (assert_unaffected, counters, delta, Every, input_fault_case,
                                 js_copy, MODEL, sensor_force, wrench_copy)
from helpers.fault_rig import DIAG_PERIOD, set_stamp, stamp_s
import numpy as np


# ----------------------------------------------------------------------------- joint states
def test_nan_in_joint_position(healthy):
    def nan_position(msg, i):
        return js_copy(msg, position=[math.nan, msg.position[1]])
    input_fault_case(healthy, 'NaN position', js=Every(5, nan_position),
                     counter='joint_state_dropped', texts=('joint state holds NaN/Inf',))


def test_inf_in_joint_velocity(healthy):
    def inf_velocity(msg, i):
        return js_copy(msg, velocity=[msg.velocity[0], math.inf if i % 2 else -math.inf])
    input_fault_case(healthy, 'Inf velocity', js=Every(5, inf_velocity),
                     counter='joint_state_dropped', texts=('joint state holds NaN/Inf',))


def test_joint_state_missing_a_controlled_joint(healthy):
    def without_joint2(msg, i):
        return js_copy(msg, name=['joint1'], position=[msg.position[0]],
                       velocity=[msg.velocity[0]], effort=[])
    input_fault_case(healthy, 'missing joint2', js=Every(5, without_joint2),
                     counter='joint_state_dropped',
                     texts=("joint state lacks controlled joint(s) ['joint2']",))


def test_wrong_length_arrays_in_joint_state(healthy):
    def wrong_length(msg, i):
        q, v = list(msg.position), list(msg.velocity)
        return [js_copy(msg, position=q + [0.0]),                     # 3 positions, 2 names
                js_copy(msg, velocity=v[:1]),                          # 1 velocity
                js_copy(msg, name=list(msg.name) + ['joint3'])][i % 3]  # 3 names, 2 values
    input_fault_case(healthy, 'wrong lengths', js=Every(5, wrong_length),
                     counter='joint_state_dropped',
                     texts=('names, positions and velocities differ in length',))


def test_reordered_and_extra_joints_do_not_disturb_tracking(healthy):
    rig = healthy

    def reordered(msg):
        return [js_copy(msg, name=['gripper_joint', msg.name[1], msg.name[0]],
                        position=[0.04, msg.position[1], msg.position[0]],
                        velocity=[0.0, msg.velocity[1], msg.velocity[0]],
                        effort=[0.0, msg.effort[1], msg.effort[0]])]
    with rig.case():
        before = rig.last_diag()
        t0, t1 = rig.fault(1.0, js=reordered)
        after = counters(rig, t1, 'reordered joints')
        assert delta(after, before, 'joint_state_dropped') == 0, after
        assert after['mode'] == 'running' and after['in_contact'] is True, after
        assert_unaffected(rig, t0, 'reordered + extra joints')


# ----------------------------------------------------------------------------- wrench
def test_nan_and_inf_in_wrench(healthy):
    def non_finite(msg, i):
        return wrench_copy(msg, force=[(math.nan, 0.0, 0.0), (0.0, math.inf, 0.0),
                                       (0.0, 0.0, -math.inf)][i % 3])
    input_fault_case(healthy, 'NaN/Inf wrench', wrench=Every(5, non_finite),
                     counter='wrench_dropped', texts=('wrench holds NaN/Inf',))


def test_wrench_in_unknown_frame_is_rejected_and_named(healthy):
    def unknown_frame(msg, i):
        return wrench_copy(msg, frame='camera_link' if i % 2 else '')
    input_fault_case(healthy, 'unknown frame', wrench=Every(5, unknown_frame),
                     counter='wrench_dropped',
                     texts=('is not a frame of the robot model',))


def test_wrench_in_base_link_is_accepted_and_rotated(healthy):
    """
    The sensor force re-expressed in base_link: F_B = R_B_tool(q) F_tool.

    Only a correct rotation keeps the normal force at f_d (R is about 90 deg here, so a wrong or
    missing rotation would turn the measured normal force into a tangential one).
    """
    rig = healthy
    rotations = []

    def in_base_link(msg):
        js = rig.proxy.js_raw
        R = MODEL.frame_rotation(np.array(js.position), 'tool0')
        f = msg.wrench.force
        F_tool = np.array([f.x, f.y, f.z])
        F_base = R @ F_tool
        rotations.append(np.linalg.norm(F_base - F_tool) / max(np.linalg.norm(F_tool), 1e-9))
        return [wrench_copy(msg, force=tuple(float(c) for c in F_base), frame='base_link')]
    with rig.case():
        before = rig.last_diag()
        t0, t1 = rig.fault(1.0, wrench=in_base_link)
        after = counters(rig, t1, 'wrench in base_link')
        assert np.median(rotations) > 1.0, 'the case is vacuous: base_link ~ tool0 here'
        assert delta(after, before, 'wrench_dropped') == 0, after
        assert after['mode'] == 'running' and after['in_contact'] is True, after
        assert_unaffected(rig, t0, 'wrench in base_link')


# ----------------------------------------------------------------------------- stamps
def test_out_of_order_joint_state_stamp(healthy):
    def older(msg, i):  # 50 ms old and far from the arm: it must never be used
        bad = js_copy(msg, position=[msg.position[0] + 0.3, msg.position[1] - 0.3])
        return set_stamp(bad, stamp_s(msg.header.stamp) - 0.05)
    input_fault_case(healthy, 'old joint state', js=Every(10, older, keep=True),
                     counter='joint_state_dropped', texts=('is older than the last one',))


def test_out_of_order_wrench_stamp(healthy):
    def older(msg, i):  # 50 ms old and 50 N: it must never be used
        return set_stamp(wrench_copy(msg, force=sensor_force(healthy, 50.0)),
                         stamp_s(msg.header.stamp) - 0.05)
    input_fault_case(healthy, 'old wrench', wrench=Every(10, older, keep=True),
                     counter='wrench_dropped', texts=('is older than the last one',))


def test_duplicate_stamps_are_harmless(healthy):
    """
    Check that every message delivered twice with the same stamp is harmless.

    A DDS re-send, for example: equal stamps are not out of order, so nothing is dropped and
    tracking is unaffected.
    """
    rig = healthy
    with rig.case():
        before = rig.last_diag()
        t0, t1 = rig.fault(0.5, js=lambda m: [m, js_copy(m)],
                           wrench=lambda m: [m, wrench_copy(m)])
        after = counters(rig, t1, 'duplicates')
        for key in ('joint_state_dropped', 'wrench_dropped', 'callback_errors_joint_states',
                    'callback_errors_wrench'):
            assert delta(after, before, key) == 0, (key, before, after)
        assert after['mode'] == 'running'
        assert_unaffected(rig, t0, 'duplicate stamps')


def test_diagnostics_come_at_diagnostic_updater_period(healthy):
    """The rig sets ``diagnostic_updater.period`` to 0.1 s: one status per 0.1 s of sim time."""
    rig = healthy
    t0 = rig.now
    rig.run_for(0.55)
    rig.diag_after(t0 + 0.5, 'the fifth status')
    with rig.proxy.cv:
        stamps = np.array([t for t, _ in rig.proxy.diags if t >= t0])
    assert stamps.size >= 5, stamps
    np.testing.assert_allclose(np.diff(stamps), DIAG_PERIOD, atol=0.0015)
