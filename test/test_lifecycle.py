"""
The controller as a managed node, driven over its lifecycle services (real DDS, real time).

``autostart:=false``: the node starts unconfigured and commands nothing; parameters can be
set (and are validated) in every state; configure -> activate starts commanding;
deactivate stops it (the sim, like a ros2_control effort controller, holds the last
command: ``command_timeout`` is long here); activate again resumes without an effort jump
(the runtime restarts from the arm's position and velocity, and its effort blends from the
held one), with no callback error and no safe mode; cleanup and shutdown are clean.
"""
from __future__ import annotations

import threading

from helpers.ros import (CONTROLLER_MODULE, domain_id, NodeProcess, SIM_MODULE, Spun, wait_for,
                         wait_future)
from helpers.watch import assert_clean_run, ForceLog
from hybrid_force_controller.ros.common.cdr import read_float64_array
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState, GetState
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray


NAME = 'hybrid_force_controller'


class _Watcher(Node):
    """Counts joint states; keeps every effort command in arrival order."""

    def __init__(self, context) -> None:
        super().__init__('lifecycle_watcher', context=context)
        self.lock = threading.Lock()
        self.js = 0
        self.efforts: list[np.ndarray] = []
        q = QoSProfile(depth=1000)
        # raw: this process must keep up with 2 kHz of input on a loaded machine (a reader that
        # falls behind still counts commands sent before a transition after it)
        self.create_subscription(JointState, 'joint_states', self._on_js, q, raw=True)
        self.create_subscription(Float64MultiArray, 'effort_controller/commands',
                                 self._on_effort, q, raw=True)
        # and the newest command only: a backlog of at most one, so "no new command" is
        # not confused with commands sent before a transition and read late
        self.newest = 0
        self.create_subscription(Float64MultiArray, 'effort_controller/commands',
                                 self._on_newest, QoSProfile(depth=1), raw=True)
        self.get_state = self.create_client(GetState, f'{NAME}/get_state')
        self.change_state = self.create_client(ChangeState, f'{NAME}/change_state')
        self.params = AsyncParameterClient(self, NAME)

    def _on_js(self, _msg) -> None:
        with self.lock:
            self.js += 1

    def _on_effort(self, raw: bytes) -> None:
        with self.lock:
            self.efforts.append(read_float64_array(raw))

    def _on_newest(self, _raw: bytes) -> None:
        with self.lock:
            self.newest += 1

    def counts(self) -> tuple[int, int]:
        with self.lock:
            return self.js, len(self.efforts)

    def state(self) -> str:
        return wait_future(self.get_state.call_async(GetState.Request())).current_state.label

    def transition(self, transition_id: int) -> bool:
        req = ChangeState.Request(transition=Transition(id=transition_id))
        return wait_future(self.change_state.call_async(req)).success

    def set_params(self, **values):
        params = [Parameter(k, value=v) for k, v in values.items()]
        return wait_future(self.params.set_parameters(params)).results


@pytest.fixture(scope='module')
def rig(tmp_path_factory):
    logs = tmp_path_factory.mktemp('lifecycle')
    domain = domain_id('lifecycle')
    sim = NodeProcess(SIM_MODULE, logs / 'sim.log', domain,  # masses 50 % off
                      ['-p', 'command_timeout:=60.0',  # holds the last command, like ros2_control
                       '-p', 'masses:=[0.65, 1.35]'])
    # a still reference: the effort the sim holds while inactive keeps the arm where it is
    # (with the sine, the held effort of a moving arm slides it along the frictionless surface,
    # and re-activation starts from wherever it got to)
    ctrl = NodeProcess(CONTROLLER_MODULE, logs / 'controller.log', domain,
                       ['-p', 'autostart:=false', '-p', 'ref_amplitude:=[0.0, 0.0, 0.0]'])
    spun = Spun(domain)
    try:
        w = spun.add(_Watcher(spun.context))
        w.force_log = ForceLog(spun)
        sim.start()
        ctrl.start()
        wait_for(lambda: w.get_state.service_is_ready() and w.change_state.service_is_ready()
                 and w.params.services_are_ready(), 'the lifecycle and parameter services',
                 alive=[sim, ctrl])
        yield w, [sim, ctrl]
    finally:
        ctrl.stop()
        sim.stop()
        spun.close()


def _no_commands_while(w: _Watcher, procs, n_js: int = 300) -> None:
    """
    Over ``n_js`` joint states, no effort command arrives.

    Counted on the depth-1 subscription, after ``n_js`` joint states first: on a loaded
    machine this process reads late, and commands sent before the transition may still be
    queued (at most one there).
    """
    js0 = w.counts()[0]
    wait_for(lambda: w.counts()[0] >= js0 + n_js, f'{n_js} joint states', alive=procs)
    js0, e0 = w.counts()[0], w.newest
    wait_for(lambda: w.counts()[0] >= js0 + n_js, f'{n_js} joint states', alive=procs)
    assert w.newest == e0, 'commands while not active'


def test_transitions_over_the_lifecycle_services_without_effort_jump(rig):
    w, procs = rig
    assert w.state() == 'unconfigured'
    _no_commands_while(w, procs)
    # parameters: model-free checks before configure
    assert w.set_params(f_d=1.0)[0].successful
    (bad,) = w.set_params(lambda1=10.0)
    assert not bad.successful and '1200' in bad.reason, bad.reason
    assert w.transition(Transition.TRANSITION_CONFIGURE)
    assert w.state() == 'inactive'
    _no_commands_while(w, procs)
    (bad,) = w.set_params(gamma=[70.0, 70.0, 70.0])  # full validation once the model is loaded
    assert not bad.successful and 'gamma' in bad.reason, bad.reason
    assert w.transition(Transition.TRANSITION_ACTIVATE)
    assert w.state() == 'active'
    e0 = w.counts()[1]
    wait_for(lambda: w.counts()[1] >= e0 + 4000, '4 s of commands', alive=procs)
    assert w.transition(Transition.TRANSITION_DEACTIVATE)
    assert w.state() == 'inactive'
    with w.lock:
        tau_last, before = w.efforts[-1].copy(), np.array(w.efforts[-500:])
    _no_commands_while(w, procs)
    e1, t1 = w.counts()[1], w.force_log.latest_t()
    assert w.transition(Transition.TRANSITION_ACTIVATE)
    wait_for(lambda: w.counts()[1] >= e1 + 1000, 'commands after re-activation', alive=procs)
    with w.lock:
        tau_first, after = w.efforts[e1].copy(), np.array(w.efforts[e1:e1 + 1000])
    jump = np.abs(tau_first - tau_last).max()
    step, step_before = (np.abs(np.diff(a, axis=0)).max() for a in (after, before))
    _, f_after = w.force_log.forces(t1)
    print(f'effort jump at re-activation {jump:.4f} N m; largest step per command: '
          f'{step_before:.4f} N m before, {step:.4f} N m after (1 s); true force after: '
          f'max {f_after.max():.2f} N')
    assert jump < 0.5, (tau_last, tau_first)  # efforts here are ~10-20 N m
    assert step < 2.0 * step_before + 0.2, (step, step_before)  # no transient beyond usual
    assert f_after.size > 50 and f_after.max() < 10.0, f_after.max()
    assert_clean_run(w.force_log.fresh_diag(NAME, procs), w.force_log.fresh_diag('sim', procs),
                     run=w.force_log.statuses(NAME))
    assert w.transition(Transition.TRANSITION_DEACTIVATE)
    assert w.transition(Transition.TRANSITION_CLEANUP)
    assert w.state() == 'unconfigured'
    assert w.set_params(f_d=1.5)[0].successful  # parameter services still work
    assert w.transition(Transition.TRANSITION_UNCONFIGURED_SHUTDOWN)
    assert w.state() == 'finalized'
    assert all(p.alive for p in procs)
