"""Closed loop over real DDS: ``sim`` (lockstep, owns /clock) + controller (use_sim_time).

Both nodes run as subprocesses with ``--params-file config/params.yaml``; this process
listens to ``/sim/contact_wrench`` (true contact force), ``/hybrid_force_controller/x``,
``/hybrid_force_controller/x_desired`` and ``/clock`` and changes ``f_d`` through the
parameter service. Lockstep makes the result independent of the machine's load.
"""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ['ROS_DOMAIN_ID'] = '74'
DOMAIN_ID = 74

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import rclpy  # noqa: E402
from geometry_msgs.msg import PointStamped, WrenchStamped  # noqa: E402
from rclpy.context import Context  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.node import Node  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.parameter_client import AsyncParameterClient  # noqa: E402
from rclpy.qos import QoSProfile  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
WALL_TIMEOUT = 300.0
N_W = np.array([0.0, -1.0, 0.0])  # config/params.yaml
P_TANGENT = np.eye(3) - np.outer(N_W, N_W)


def _t(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


class _Listener(Node):
    """Collects (stamp, vector) series; ``clock`` is the latest /clock in seconds."""

    def __init__(self, context):
        super().__init__('closed_loop_listener', context=context)
        self.clock = 0.0
        self.force, self.x, self.x_d = {}, {}, {}
        qos = QoSProfile(depth=1000)
        self.create_subscription(Clock, '/clock', self._on_clock, qos)
        self.create_subscription(WrenchStamped, '/sim/contact_wrench', self._on_force, qos)
        self.create_subscription(PointStamped, '/hybrid_force_controller/x',
                                 lambda m: self._point(self.x, m), qos)
        self.create_subscription(PointStamped, '/hybrid_force_controller/x_desired',
                                 lambda m: self._point(self.x_d, m), qos)

    def _on_clock(self, msg):
        self.clock = max(self.clock, _t(msg.clock))

    def _on_force(self, msg):
        f = msg.wrench.force
        self.force[_t(msg.header.stamp)] = np.array([f.x, f.y, f.z])

    @staticmethod
    def _point(store, msg):
        store[_t(msg.header.stamp)] = np.array([msg.point.x, msg.point.y, msg.point.z])

    def force_error_rms(self, t0, t1, f_d):
        e = [N_W @ f - f_d for t, f in self.force.items() if t0 <= t <= t1]
        assert len(e) > 0.5 * (t1 - t0) * 1000, f'only {len(e)} force samples in [{t0}, {t1}]'
        return float(np.sqrt(np.mean(np.square(e))))

    def tangential_error_rms(self, t0, t1):
        e = [P_TANGENT @ (x - self.x_d[t]) for t, x in self.x.items()
             if t0 <= t <= t1 and t in self.x_d]
        assert len(e) > 0.5 * (t1 - t0) * 1000, f'only {len(e)} position pairs in [{t0}, {t1}]'
        return float(np.sqrt(np.mean(np.sum(np.square(e), axis=1))))


def _start(module, log_path, *overrides):
    env = dict(os.environ, PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(DOMAIN_ID),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    cmd = [sys.executable, '-m', module, '--ros-args',
           '--params-file', str(ROOT / 'config' / 'params.yaml')]
    for override in overrides:
        cmd += ['-p', override]
    log = open(log_path, 'w')
    return subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT), log


def _stop(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)


@pytest.fixture(scope='module')
def loop(tmp_path_factory):
    logs = tmp_path_factory.mktemp('closed_loop')
    procs = []
    context = Context()
    rclpy.init(context=context, domain_id=DOMAIN_ID)
    listener = _Listener(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(listener)
    try:
        procs.append(_start('sim_node.sim_node', logs / 'sim.log', 'lockstep:=true'))
        procs.append(_start('hybrid_force_controller.ros.controller_node', logs / 'controller.log',
                            'use_sim_time:=true'))

        def spin_until(condition, what):
            deadline = time.monotonic() + WALL_TIMEOUT
            while not condition():
                for proc, log in procs:
                    if proc.poll() is not None:
                        pytest.fail(f'{proc.args[2]} exited with {proc.returncode}:\n'
                                    + Path(log.name).read_text()[-3000:])
                if time.monotonic() > deadline:
                    pytest.fail(f'timed out waiting for {what}; sim time {listener.clock:.3f} s\n'
                                + '\n'.join(Path(log.name).read_text()[-2000:] for _, log in procs))
                executor.spin_once(timeout_sec=0.1)

        yield listener, spin_until
    finally:
        for proc, log in procs:
            _stop(proc)
            log.close()
        executor.shutdown()
        listener.destroy_node()
        rclpy.try_shutdown(context=context)


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
    future = client.set_parameters([Parameter('f_d', value=2.0)])
    spin_until(future.done, 'the set_parameters answer')
    assert future.result().results[0].successful, future.result().results[0].reason
    t_change = listener.clock
    spin_until(lambda: listener.clock >= t_change + 2.0, '2 s after the change')
    t1 = listener.clock
    assert listener.force_error_rms(t1 - 1.0, t1, 2.0) <= 0.05
