"""
Closed loop over real DDS: ``sim`` (lockstep, owns /clock) + controller (use_sim_time).

Both nodes run as subprocesses with ``--params-file config/params.yaml``; this process
listens to ``/sim/contact_wrench`` (true contact force), ``/hybrid_force_controller/x``,
``/hybrid_force_controller/x_desired`` and ``/clock`` and changes ``f_d`` through the
parameter service. Lockstep makes the result independent of the machine's load.
"""
import threading

from geometry_msgs.msg import PointStamped, WrenchStamped
from helpers.ros import domain_id, NodeProcess, Spun, stamp_s, wait_for, wait_future
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock


WALL_TIMEOUT = 300.0
N_W = np.array([0.0, -1.0, 0.0])  # config/params.yaml
P_TANGENT = np.eye(3) - np.outer(N_W, N_W)


class _Listener(Node):
    """Collects (stamp, vector) series; ``clock`` is the latest /clock in seconds."""

    def __init__(self, context):
        super().__init__('closed_loop_listener', context=context)
        self.clock = 0.0
        self.lock = threading.Lock()  # the executor thread adds samples while the test reads
        self.force, self.x, self.x_d = {}, {}, {}
        qos = QoSProfile(depth=1000)
        self.create_subscription(Clock, '/clock', self._on_clock, qos)
        self.create_subscription(WrenchStamped, '/sim/contact_wrench', self._on_force, qos)
        self.create_subscription(PointStamped, '/hybrid_force_controller/x',
                                 lambda m: self._point(self.x, m), qos)
        self.create_subscription(PointStamped, '/hybrid_force_controller/x_desired',
                                 lambda m: self._point(self.x_d, m), qos)

    def _on_clock(self, msg):
        self.clock = max(self.clock, stamp_s(msg.clock))

    def _on_force(self, msg):
        f = msg.wrench.force
        with self.lock:
            self.force[stamp_s(msg.header.stamp)] = np.array([f.x, f.y, f.z])

    def _point(self, store, msg):
        with self.lock:
            store[stamp_s(msg.header.stamp)] = np.array([msg.point.x, msg.point.y, msg.point.z])

    def force_error_rms(self, t0, t1, f_d):
        with self.lock:
            force = list(self.force.items())
        e = [N_W @ f - f_d for t, f in force if t0 <= t <= t1]
        assert len(e) > 0.5 * (t1 - t0) * 1000, f'only {len(e)} force samples in [{t0}, {t1}]'
        return float(np.sqrt(np.mean(np.square(e))))

    def tangential_error_rms(self, t0, t1):
        with self.lock:
            x_d, x = dict(self.x_d), list(self.x.items())
        e = [P_TANGENT @ (x_t - x_d[t]) for t, x_t in x if t0 <= t <= t1 and t in x_d]
        assert len(e) > 0.5 * (t1 - t0) * 1000, f'only {len(e)} position pairs in [{t0}, {t1}]'
        return float(np.sqrt(np.mean(np.sum(np.square(e), axis=1))))


@pytest.fixture(scope='module')
def loop(tmp_path_factory):
    logs = tmp_path_factory.mktemp('closed_loop')
    domain = domain_id('nodes_closed_loop')
    full = ['-p', 'telemetry_rate_hz:=1000.0']  # every step: the test counts samples
    procs = [NodeProcess('sim_node.sim_node', logs / 'sim.log', domain,
                         ['-p', 'lockstep:=true', *full]),
             NodeProcess('hybrid_force_controller.ros.controller.controller_node',
                         logs / 'controller.log',
                         domain, ['-p', 'use_sim_time:=true', *full])]
    spun = Spun(domain)
    listener = spun.add(_Listener(spun.context))
    try:
        for proc in procs:
            proc.start()

        def spin_until(condition, what):
            wait_for(condition, f'{what} (sim time {listener.clock:.3f} s)', WALL_TIMEOUT, procs)

        yield listener, spin_until
    finally:
        for proc in procs:
            proc.stop()
        spun.close()


def test_tracks_position_and_force(loop):
    listener, spin_until = loop
    spin_until(lambda: listener.clock >= 8.0, 'sim time 8 s')
    t1 = min(listener.clock, 8.0)
    assert listener.tangential_error_rms(5.0, t1) <= 0.5e-3
    assert listener.force_error_rms(5.0, t1, 1.0) <= 0.05


def test_force_setpoint_change_through_parameter_service(loop):
    listener, spin_until = loop
    client = AsyncParameterClient(listener, 'hybrid_force_controller')
    spin_until(client.services_are_ready, 'the parameter services')
    result = wait_future(client.set_parameters([Parameter('f_d', value=2.0)]))
    assert result.results[0].successful, result.results[0].reason
    t_change = listener.clock
    spin_until(lambda: listener.clock >= t_change + 2.0, '2 s after the change')
    t1 = listener.clock
    assert listener.force_error_rms(t1 - 1.0, t1, 2.0) <= 0.05
