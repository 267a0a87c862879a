"""
Closed loop in real time over real DDS (no lockstep): sim and controller on the wall clock.

(a) the sim's link masses are 50 % off the URDF's (0.65 and 1.35 kg vs 1.3 and 0.9 kg), with
a recorder process subscribed to every topic: contact is kept, the force stays bounded and the
tool tracks the path within loose bounds; (c) the controller process
is frozen (SIGSTOP/SIGCONT by pid) for 30 ms a few times: the force comes back near f_d,
no effort exceeds the limits and the process lives on. Plus the sim alone: it holds the arm
still until the first command, and its physics keeps up with wall time when its own process
is frozen (a late callback integrates the missed periods).

The thresholds are loose on purpose (a loaded 2-core machine): the exact figures are what
``bench --ros`` reports. Times are message stamps (node clock = wall clock here); waits
have a wall timeout that only guards against hangs.
"""
from __future__ import annotations

import signal
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, WrenchStamped
from helpers.ros import domain_id, NodeProcess, parse_diagnostics, Spun, stamp_s, wait_for
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray


CTRL = 'hybrid_force_controller.ros.controller.controller_node'
N_W = np.array([0.0, -1.0, 0.0])
P_TANGENT = np.eye(3) - np.outer(N_W, N_W)
F_D = 1.0
MASSES_OFF = ['-p', 'masses:=[0.65, 1.35]']  # URDF: 1.3, 0.9 (each 50 % off)
RUN_S = 10.0


class _Watcher(Node):
    """True force, position, reference, efforts and diagnostics, stamped (seconds)."""

    def __init__(self, context) -> None:
        super().__init__('realtime_watcher', context=context)
        self.lock = threading.Lock()
        self.force: list[tuple[float, float]] = []
        self.x: dict[float, np.ndarray] = {}
        self.x_d: dict[float, np.ndarray] = {}
        self.max_effort = 0.0
        self.efforts = 0
        self.diags: dict[str, dict] = {}
        self.js: list[tuple[float, np.ndarray]] = []
        q = QoSProfile(depth=1000)
        self.create_subscription(WrenchStamped, 'sim/contact_wrench', self._on_force, q)
        self.create_subscription(PointStamped, 'hybrid_force_controller/x',
                                 lambda m: self._point(self.x, m), q)
        self.create_subscription(PointStamped, 'hybrid_force_controller/x_desired',
                                 lambda m: self._point(self.x_d, m), q)
        self.create_subscription(Float64MultiArray, 'effort_controller/commands',
                                 self._on_effort, q)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, q)
        self.create_subscription(JointState, 'joint_states', self._on_js, q)

    def _on_force(self, msg) -> None:
        f = msg.wrench.force
        with self.lock:
            self.force.append((stamp_s(msg.header.stamp), float(N_W @ [f.x, f.y, f.z])))

    def _point(self, store, msg) -> None:
        with self.lock:
            store[stamp_s(msg.header.stamp)] = np.array([msg.point.x, msg.point.y, msg.point.z])

    def _on_effort(self, msg) -> None:
        with self.lock:
            self.efforts += 1
            if len(msg.data):
                self.max_effort = max(self.max_effort, float(np.max(np.abs(msg.data))))

    def _on_diag(self, msg) -> None:
        d = parse_diagnostics(msg)
        d['received_s'] = time.monotonic()
        d['stamp_s'] = stamp_s(msg.header.stamp)  # the publisher's clock when it reported
        with self.lock:
            self.diags[msg.status[0].hardware_id] = d

    def _on_js(self, msg) -> None:
        with self.lock:
            if len(self.js) < 100000:
                self.js.append((stamp_s(msg.header.stamp), np.array(msg.position)))

    def latest_force_t(self) -> float:
        with self.lock:
            return self.force[-1][0] if self.force else 0.0

    def forces(self, t0: float, t1: float) -> np.ndarray:
        with self.lock:
            return np.array([f for t, f in self.force if t0 <= t <= t1])

    def tangential_rms(self, t0: float, t1: float) -> float:
        with self.lock:
            pairs = [(x, self.x_d[t]) for t, x in self.x.items()
                     if t0 <= t <= t1 and t in self.x_d]
        assert len(pairs) > 10, f'only {len(pairs)} position samples in [{t0:.2f}, {t1:.2f}]'
        e = [P_TANGENT @ (x - x_d) for x, x_d in pairs]
        return float(np.sqrt(np.mean(np.sum(np.square(e), axis=1))))


class _Run:
    """One real-time run: processes + watcher; everything stopped by pid on every path."""

    def __init__(self, tmp_path, recorder: bool = False) -> None:
        self.domain = domain_id('realtime')
        self.sim = NodeProcess('sim_node.sim_node', tmp_path / 'sim.log', self.domain,
                               MASSES_OFF)
        self.ctrl = NodeProcess(CTRL, tmp_path / 'controller.log', self.domain)
        self.procs = [self.sim, self.ctrl]
        if recorder:
            self.procs.append(NodeProcess('hybrid_force_controller.ros.programs.recorder_node',
                                          tmp_path / 'recorder.log', self.domain,
                                          params_file=None, argv=[str(tmp_path / 'bag')]))
        self.spun: Spun | None = None

    def __enter__(self) -> '_Run':
        try:
            self.spun = Spun(self.domain)
            self.w = self.spun.add(_Watcher(self.spun.context))
            for p in self.procs:
                p.start()
            wait_for(lambda: self.w.latest_force_t() > 0.0 and len(self.w.x) > 0,
                     'the loop to run', alive=self.procs)
            self.t_start = self.w.latest_force_t()
        except BaseException:
            self.__exit__()
            raise
        return self

    def __exit__(self, *exc) -> None:
        for p in self.procs:
            p.stop()
        if self.spun is not None:
            self.spun.close()

    def run_until(self, t: float) -> None:
        wait_for(lambda: self.w.latest_force_t() >= t, f'stamp {t:.1f}', alive=self.procs)

    def tails(self) -> str:
        return '\n'.join(p.tail(1500) for p in self.procs)


def _assert_contact_and_tracking(run: _Run, t0: float, t1: float) -> dict:
    f = run.w.forces(t0, t1)
    assert f.size > 0.3 * (t1 - t0) * 100, f'{f.size} force samples\n{run.tails()}'
    figures = {'f_min': float(f.min()), 'f_max': float(f.max()),
               'f_rms_err': float(np.sqrt(np.mean((f - F_D) ** 2))),
               'x_rms_err': run.w.tangential_rms(t0, t1), 'max_effort': run.w.max_effort}
    print('figures', figures)
    assert figures['f_min'] > 0.0, f'contact lost: {figures}\n{run.tails()}'
    assert figures['f_max'] < 5.0 * F_D, f'force not bounded: {figures}\n{run.tails()}'
    assert figures['f_rms_err'] < 0.3, f'force far from f_d: {figures}\n{run.tails()}'
    assert figures['x_rms_err'] < 5e-3, f'tracking: {figures}\n{run.tails()}'
    return figures


# with a recorder only: it is the loop alone plus a reader of every topic (the alone run took
# 15 s more of the suite and checked a subset of it)
@pytest.mark.parametrize('recorder', [True], ids=['with_recorder'])
def test_real_time_loop_with_masses_50_percent_off(tmp_path, recorder):
    with _Run(tmp_path, recorder=recorder) as run:
        t0 = run.t_start + 4.0  # after the start blend (ref_blend_time 2 s) and settling
        run.run_until(t0 + RUN_S)
        _assert_contact_and_tracking(run, t0, t0 + RUN_S)
    if recorder:
        assert (tmp_path / 'bag' / 'metadata.yaml').is_file(), run.tails()


def test_controller_frozen_30_ms_recovers(tmp_path):
    with _Run(tmp_path) as run:
        run.run_until(run.t_start + 4.0)
        for _ in range(5):
            run.ctrl.signal(signal.SIGSTOP)
            time.sleep(0.03)  # the fault itself (a frozen process), not a wait
            run.ctrl.signal(signal.SIGCONT)
            t = run.w.latest_force_t()
            run.run_until(t + 1.0)
        t1 = run.w.latest_force_t()
        run.run_until(t1 + 2.0)
        f = run.w.forces(t1 + 1.0, t1 + 2.0)
        assert f.size and np.all(np.abs(f - F_D) < 0.3), (f.min(), f.max(), run.tails())


def test_sim_holds_the_arm_until_the_first_command(tmp_path):
    domain = domain_id('sim_node')
    sim = NodeProcess('sim_node.sim_node', tmp_path / 'sim.log', domain)
    with Spun(domain) as spun:
        w = spun.add(_Watcher(spun.context))
        with sim:
            wait_for(lambda: len(w.js) > 300, '300 joint states', alive=[sim])
            with w.lock:
                q = np.array([p for _, p in w.js])
            np.testing.assert_array_equal(q, np.broadcast_to(q[0], q.shape))  # brakes: no motion
            np.testing.assert_allclose(q[0], [0.657, 0.913])


def test_sim_physics_keeps_wall_time_when_its_process_stalls(tmp_path):
    """
    Freeze the sim for 30 ms (< max_catch_up): the late callback catches up.

    It integrates the missed periods, so sim time keeps pace with the wall clock and
    nothing is dropped.
    """
    domain = domain_id('sim_node')
    sim = NodeProcess('sim_node.sim_node', tmp_path / 'sim.log', domain)
    with Spun(domain) as spun:
        w = spun.add(_Watcher(spun.context))
        with sim:
            wait_for(lambda: 'sim' in w.diags, 'sim diagnostics', alive=[sim])
            d0 = dict(w.diags['sim'])
            for _ in range(5):
                sim.signal(signal.SIGSTOP)
                time.sleep(0.03)  # the fault itself
                sim.signal(signal.SIGCONT)
                time.sleep(0.2)
            wait_for(lambda: w.diags['sim']['sim_time_s'] > d0['sim_time_s'] + 3.0,
                     'three more seconds of sim time', alive=[sim])
            d1 = dict(w.diags['sim'])
    # both from the sim's own reports: its sim time against its wall clock when it reported
    # (not this process's reception times, which a loaded machine delays)
    sim_elapsed = d1['sim_time_s'] - d0['sim_time_s']
    wall_elapsed = d1['stamp_s'] - d0['stamp_s']
    assert d1['late_callbacks'] > d0['late_callbacks']
    assert d1['lost_periods'] == d0['lost_periods'] == 0, (d0, d1)
    # without the catch-up, the five freezes alone would put sim time 0.15 s behind
    assert abs(sim_elapsed - wall_elapsed) < 0.1, (sim_elapsed, wall_elapsed)
