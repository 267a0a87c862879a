"""
The sim's command watchdog acts per period, also over periods its thread was held for.

On a robot the hardware keeps running while nobody reads; the sim's thread can be held, by a
publish that blocks on a stopped reader's shared-memory port (Fast DDS), as when the
controller is frozen with SIGSTOP while it holds that port's lock (py-spy showed the sim in
``SharedMemManager::Port::try_push`` under ``taskset -c 0``). The periods it missed are run
when it resumes: the old command for ``command_timeout`` after it came, zero effort after.
"""
import math
import time

from helpers.ros import domain_id
import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message
from sim_node.sim_node import held_periods, SimNode
from std_msgs.msg import Float64MultiArray


TIMEOUT_S = 0.2


@pytest.mark.parametrize('t_cmd, expected', [
    (0.0, 20),    # the command at t_begin: held for 0.2 s = 20 of the 30 periods of 10 ms
    (-0.05, 15),  # 50 ms older: 15
    (-1.0, 0),    # timed out before the first period ended: none
    (0.5, 30),    # fresh for all of them
    (-math.inf, 0),  # no command yet
])
def test_held_periods_end_within_the_timeout_of_the_command(t_cmd, expected):
    assert held_periods(0.0, 30, 0.01, t_cmd, TIMEOUT_S) == expected


def test_held_periods_includes_the_period_ending_at_the_timeout():
    """Period k ends at t_begin + k dt; it is held when that is <= t_cmd + timeout."""
    assert held_periods(0.0, 30, 0.01, 0.0, 0.1) == 10
    assert held_periods(0.0, 30, 0.01, 0.0, 0.1 - 1e-6) == 9


@pytest.fixture
def sim():
    context = Context()
    rclpy.init(context=context, domain_id=domain_id('sim_watchdog'))
    node = SimNode(context=context, parameter_overrides=[
        Parameter('command_timeout', value=TIMEOUT_S), Parameter('max_catch_up', value=10000)])
    yield node
    node.destroy_node()
    context.try_shutdown()


def _command(tau) -> bytes:
    return serialize_message(Float64MultiArray(data=list(tau)))


def _command_after(sim, wait_s: float, tau) -> tuple[int, int]:
    """
    Send ``tau`` ``wait_s`` from now; return the steps its callback ran and the periods passed.

    The wait is a bare sleep: the stimulus (the held thread), not a wait on a condition.
    """
    steps, t = sim.counters['steps'], time.monotonic()
    time.sleep(wait_s)
    sim._on_command(_command(tau))
    return sim.counters['steps'] - steps, round((time.monotonic() - t) / sim.dt) + 1


def test_a_command_after_a_held_thread_first_runs_the_missed_periods(sim):
    """
    A command runs the periods that ended before it on the old one, then takes over.

    20 ms after the first command: about 20 periods, no timeout. After 0.5 s held (the
    stimulus: a bare sleep stands for the blocked publish): about 500 periods, the first
    200 on the old command, the rest on zero effort, counted as one timeout.
    """
    tau0, tau1 = np.array([0.5, 0.2]), np.array([0.4, 0.1])
    sim._on_command(_command(tau0))
    steps, passed = _command_after(sim, 0.02, tau0)
    assert 15 <= steps <= passed, steps
    assert sim.counters['command_timeouts'] == 0
    steps, passed = _command_after(sim, 0.5, tau1)
    assert 495 <= steps <= passed, steps
    assert sim.counters['command_timeouts'] == 1
    assert np.array_equal(sim.tau_cmd, tau1)  # taken after the catch-up, fresh
    time.sleep(0.01)
    sim._advance()  # the timer's call: the periods since run on the new command
    assert sim.counters['command_timeouts'] == 1


def test_the_spin_loop_steps_the_sim_at_its_period_without_a_timer(sim):
    """
    ``take_pacing`` hands the step to run_node's loop, and the timer is gone.

    The function it returns steps the periods that ended and says how long until the next one
    ends. The 20 ms between two calls is the stimulus (a bare sleep: the loop spun meanwhile).
    """
    pace = sim.take_pacing()
    assert sim.timer is None
    sim._on_command(_command([0.1, 0.1]))
    pace()
    steps, t = sim.counters['steps'], time.monotonic()
    time.sleep(0.02)
    wait = pace()
    passed = (time.monotonic() - t) / sim.dt
    assert 0.0 <= wait <= sim.dt
    assert passed - 1.0 <= sim.counters['steps'] - steps <= passed + 1.0
    assert pace() >= 0.0 and sim.counters['errors'] == 0


def test_lockstep_keeps_its_watchdog_timer():
    context = Context()
    rclpy.init(context=context, domain_id=domain_id('sim_watchdog'))
    sim = SimNode(context=context, parameter_overrides=[Parameter('lockstep', value=True)])
    try:
        assert sim.take_pacing() is None and sim.timer is not None
    finally:
        sim.destroy_node()
        context.try_shutdown()


@pytest.mark.parametrize('action', ['zero', 'brake'])
def test_the_watchdog_action_lets_the_arm_fall_or_brakes_it(action):
    """
    After ``command_timeout``: zero effort (the arm falls) or the brakes (it stops and holds).

    The surface is off and the first command is no effort at all, so the arm is already
    falling when the watchdog acts. 0.5 s held: 200 periods on that command, 300 after it.
    """
    context = Context()
    rclpy.init(context=context, domain_id=domain_id('sim_watchdog'))
    sim = SimNode(context=context, parameter_overrides=[
        Parameter('command_timeout', value=TIMEOUT_S), Parameter('max_catch_up', value=10000),
        Parameter('surface_enabled', value=False), Parameter('watchdog_action', value=action)])
    try:
        sim._on_command(_command([0.0, 0.0]))
        q0 = sim.sim.q.copy()
        time.sleep(0.5)  # the stimulus: the sim's thread held past command_timeout
        sim._advance()
        assert sim.counters['command_timeouts'] == 1
        moved = np.abs(sim.sim.q - q0).max()
        assert moved > 0.01, moved  # it fell during the 0.2 s of the held command
        if action == 'brake':
            assert np.all(sim.sim.qdot == 0.0), sim.sim.qdot
            q_held = sim.sim.q.copy()
            time.sleep(0.05)
            sim._advance()
            assert np.array_equal(sim.sim.q, q_held)  # held still while no command comes
        else:
            assert np.abs(sim.sim.qdot).max() > 1.0, sim.sim.qdot  # still falling, faster
    finally:
        sim.destroy_node()
        context.try_shutdown()


def test_an_unknown_watchdog_action_is_refused():
    context = Context()
    rclpy.init(context=context, domain_id=domain_id('sim_watchdog'))
    try:
        with pytest.raises(ValueError, match='watchdog_action must be one of'):
            SimNode(context=context, parameter_overrides=[
                Parameter('watchdog_action', value='float')])
    finally:
        context.try_shutdown()


def test_lockstep_steps_without_a_command_after_0_2_s_then_after_lockstep_watchdog():
    """
    Lockstep: a step per 0.2 s of silence before the first command, per lockstep_watchdog then.

    Once commands came, a slow answer is waited for, so a busy machine slows the run instead
    of changing it. The silence is set on the sim's own clock of its last publish (``t_pub``),
    no sleep.
    """
    context = Context()
    rclpy.init(context=context, domain_id=domain_id('sim_watchdog'))
    sim = SimNode(context=context, parameter_overrides=[
        Parameter('lockstep', value=True), Parameter('lockstep_watchdog', value=1.5)])
    try:
        def steps_after_silence(silence_s: float) -> int:
            steps = sim.counters['steps']
            sim.t_pub = time.monotonic() - silence_s
            sim._on_watchdog()
            return sim.counters['steps'] - steps
        assert steps_after_silence(0.0) == 0
        assert steps_after_silence(0.25) == 1  # no command yet: the controller's first tick
        sim._on_command(_command([0.1, 0.1]))
        assert sim.counters['steps'] > 0 and sim.counters['watchdog_steps'] == 1
        assert steps_after_silence(0.25) == 0  # the commands flow: a slow answer is waited for
        assert steps_after_silence(1.0) == 0
        assert steps_after_silence(1.6) == 1
        assert sim.counters['watchdog_steps'] == 2
    finally:
        sim.destroy_node()
        context.try_shutdown()


def test_lockstep_watchdog_is_set_at_run_time_and_a_refused_value_changes_nothing():
    """A set of lockstep_watchdog applies at once; one outside 0.01-60 s is refused, named."""
    context = Context()
    rclpy.init(context=context, domain_id=domain_id('sim_watchdog'))
    sim = SimNode(context=context, parameter_overrides=[Parameter('lockstep', value=True)])
    try:
        assert sim.lockstep_watchdog == 2.0
        assert sim.set_parameters([Parameter('lockstep_watchdog', value=0.2)])[0].successful
        assert sim.lockstep_watchdog == 0.2
        for bad in (0.001, 100.0, 'fast'):
            result = sim.set_parameters([Parameter('lockstep_watchdog', value=bad)])[0]
            assert not result.successful and 'lockstep_watchdog' in result.reason, result
            assert sim.lockstep_watchdog == 0.2
            assert sim.get_parameter('lockstep_watchdog').value == 0.2
    finally:
        sim.destroy_node()
        context.try_shutdown()
