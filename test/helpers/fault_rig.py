"""
Fault-injection rig over real DDS: sim and controller processes with a proxy in between.

The ``sim`` process (lockstep: it owns the time) publishes its joint states, its wrench and
its ``/clock`` under :data:`RAW`; the :class:`Proxy` node in the test process forwards the
first two to ``/joint_states`` and ``/force_torque_sensor_broadcaster/wrench``, passing each
message through the current fault hook (drop, corrupt, reorder, duplicate, inject), and then
publishes ``/clock`` with their stamp. So the controller process (``use_sim_time``) sees
only what the proxy forwards, and its time cannot run ahead of the proxy (a stalled test
process must not look like stale inputs). The proxy also watches every effort the
controller publishes (finite, within the effort limits and the per-tick rate limit in
force) and ``/diagnostics``. Sim time and the true contact force are read off the raw
messages (no sensor noise in this rig and a frictionless surface, so the force is along n
and its size is the norm of the raw sensor force). The proxy spins in a background
thread (:class:`~helpers.ros.Spun`); tests wait on conditions (:func:`~helpers.ros.wait_for`),
with a wall timeout that only guards against a hang (no assertion is about wall time). The
cases' own helpers are in :mod:`helpers.fault_cases`.
"""
from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
import threading
from typing import Any, Callable, Iterator

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import WrenchStamped
from helpers.ros import (CONTROLLER_MODULE, NodeProcess, parse_diagnostics, SIM_MODULE, Spun,
                         stamp_s, wait_for, wait_future)
import numpy as np
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, MultiArrayDimension


RAW = '/fault_injection/raw'
WALL_TIMEOUT = 90.0  # only against hangs
LOCKSTEP_WATCHDOG = 2.0  # the sim's default, wall s without a command before it steps anyway
DIAG_PERIOD = 0.1  # the controller's /diagnostics period here, s of sim time
QUICK_WATCHDOG = 0.2     # the same while a case stops the controller (Rig.quick_watchdog)
INJECTED = 'fault_injection'  # layout label of commands this process publishes itself
Hook = Callable[[Any], list]


def set_stamp(msg, t: float):
    msg.header.stamp.sec, msg.header.stamp.nanosec = int(t), int(round((t - int(t)) * 1e9))
    return msg


class Proxy(Node):
    """Forwards the sim's outputs to the controller through fault hooks; watches the loop."""

    def __init__(self, context: Any, n_W: np.ndarray, limits: np.ndarray) -> None:
        super().__init__('fault_injector', context=context)
        self.cv = threading.Condition()
        self.n_W = n_W
        self.js_hook: Hook | None = None
        self.wrench_hook: Hook | None = None
        self.now = 0.0          # stamp of the latest raw joint state = sim time, s
        self.clock_jumps = 0    # backward jumps of the raw clock (sim restarts)
        self.js_raw: JointState | None = None
        self.js_log: list[tuple[float, JointState]] = []
        self.force_log: list[tuple[float, float]] = []
        self.f_d, self.f_tol = 1.0, 0.05
        self.t_force_bad = self.t_force_last = -np.inf
        self.cmds: list[tuple[float, np.ndarray]] = []
        self.cmds_from = 0  # index of the first command on the current clock
        self.violations: list[str] = []
        self.limits, self.rate, self.rate_from = limits.copy(), 0.0, np.inf
        self.diags: list[tuple[float, dict[str, Any]]] = []
        q_out, q_in = QoSProfile(depth=10), QoSProfile(depth=1000)
        self.pub_js = self.create_publisher(JointState, '/joint_states', q_out)
        self.pub_wrench = self.create_publisher(WrenchStamped,
                                                '/force_torque_sensor_broadcaster/wrench', q_out)
        self.pub_clock = self.create_publisher(Clock, '/clock', q_out)
        self._handled = {'js': -1.0, 'wrench': -1.0}
        self.pub_cmd = self.create_publisher(Float64MultiArray, '/effort_controller/commands',
                                             q_out)
        self.create_subscription(JointState, f'{RAW}/joint_states', self._on_js, q_in)
        self.create_subscription(WrenchStamped, f'{RAW}/wrench', self._on_wrench, q_in)
        self.create_subscription(Float64MultiArray, '/effort_controller/commands',
                                 self._on_command, q_in)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, q_in)

    # ------------------------------------------------------------- forwarding
    def _on_js(self, msg: JointState) -> None:
        hook = self.js_hook
        for out in ([msg] if hook is None else hook(msg)):
            self.pub_js.publish(out)
        t = stamp_s(msg.header.stamp)
        self._tick('js', msg)
        with self.cv:
            if t < self.now - 0.5:  # the sim restarted: its time starts again from zero
                self.clock_jumps += 1
                self.t_force_bad = t
                self.diags.clear()  # the logs by time restart with the new clock
                self.js_log.clear()
                self.force_log.clear()
                self.cmds_from = len(self.cmds)
            self.now, self.js_raw = t, msg
            self.js_log.append((t, msg))
            self.cv.notify_all()

    def _on_wrench(self, msg: WrenchStamped) -> None:
        hook = self.wrench_hook
        for out in ([msg] if hook is None else hook(msg)):
            self.pub_wrench.publish(out)
        self._tick('wrench', msg)
        f = msg.wrench.force
        f_n = (f.x * f.x + f.y * f.y + f.z * f.z) ** 0.5  # true force: along n, no noise
        t = stamp_s(msg.header.stamp)
        self.force_log.append((t, f_n))
        if abs(f_n - self.f_d) > self.f_tol:
            self.t_force_bad = t
        self.t_force_last = t

    def _tick(self, which: str, msg) -> None:
        """/clock at a stamp once both of the sim's messages of that stamp were handled."""
        t = stamp_s(msg.header.stamp)
        self._handled[which] = t
        if self._handled['js'] == self._handled['wrench'] == t:
            self.pub_clock.publish(Clock(clock=msg.header.stamp))
            self._handled['js'] = -1.0

    # ------------------------------------------------------------- watching
    def _on_command(self, msg: Float64MultiArray) -> None:
        if msg.layout.dim and msg.layout.dim[0].label == INJECTED:
            return
        tau = np.array(msg.data, dtype=float)
        with self.cv:
            t = self.now
            problem = None
            if tau.shape != self.limits.shape:
                problem = f'effort of length {tau.size}'
            elif not np.all(np.isfinite(tau)):
                problem = 'NaN/Inf effort'
            elif np.any(np.abs(tau) > self.limits + 1e-9):
                problem = f'effort beyond the limits {self.limits.tolist()}'
            elif self.rate > 0.0 and t >= self.rate_from and len(self.cmds) > self.cmds_from:
                step = np.abs(tau - self.cmds[-1][1]).max()
                if step > self.rate + 1e-9:
                    problem = f'effort step {step:.4g} > max_effort_rate {self.rate:g}'
            if problem:
                self.violations.append(f't={t:.3f}: {problem}: {tau.tolist()}')
            self.cmds.append((t, tau))
            self.cv.notify_all()

    def _on_diag(self, msg: DiagnosticArray) -> None:
        if not msg.status or msg.status[0].hardware_id != 'hybrid_force_controller':
            return  # the sim reports on /diagnostics too
        t = stamp_s(msg.header.stamp)
        with self.cv:
            if t <= self.now + 0.5:  # else stamped before a restart of the sim's clock
                self.diags.append((t, parse_diagnostics(msg)))
            self.cv.notify_all()

    # ------------------------------------------------------------- injecting
    def inject_command(self, data: list[float]) -> None:
        """Publish a command to the sim, marked so the effort monitor skips it."""
        msg = Float64MultiArray(data=[float(x) for x in data])
        msg.layout.dim = [MultiArrayDimension(label=INJECTED, size=len(data), stride=len(data))]
        self.pub_cmd.publish(msg)


class Rig:
    """sim + controller + proxy in one DDS domain; see the module docstring."""

    def __init__(self, logs: Path, domain_id: int, n_W: np.ndarray, limits: np.ndarray,
                 sim_args: list[str], controller_args: list[str]) -> None:
        remap = ['-r', f'/joint_states:={RAW}/joint_states',
                 '-r', f'/force_torque_sensor_broadcaster/wrench:={RAW}/wrench',
                 '-r', f'/clock:={RAW}/clock']
        self.sim = NodeProcess(SIM_MODULE, logs / 'sim.log', domain_id,
                               ['-p', 'lockstep:=true', *sim_args, *remap])
        self.controller = NodeProcess(CONTROLLER_MODULE,
                                      logs / 'controller.log', domain_id,
                                      ['-p', 'use_sim_time:=true', *controller_args,
                                       # a status every 0.1 s of sim time: the cases wait for
                                       # the one after their fault (1 s: a third of the time)
                                       '-p', f'diagnostic_updater.period:={DIAG_PERIOD}',
                                       # every injected message is counted: reliable inputs
                                       # that keep a burst (the defaults keep only the newest)
                                       '-p', 'sensor_qos:=reliable', '-p', 'sensor_depth:=10'])
        self.spun = Spun(domain_id)
        self.proxy = self.spun.add(Proxy(self.spun.context, n_W, limits))
        self.params = AsyncParameterClient(self.proxy, 'hybrid_force_controller')
        self.sim_params = AsyncParameterClient(self.proxy, 'sim')
        self.expect_alive = {'sim': True, 'controller': True}
        self.broken = False  # a case failed: the next one resets the rig first

    # ------------------------------------------------------------- lifecycle
    def start(self) -> None:
        self.sim.start()
        self.controller.start()

    def reset(self, within: float = 10.0) -> None:
        """Restart both processes (defaults again) and wait for tracking."""
        jumps = self.proxy.clock_jumps
        self.controller.kill()
        self.sim.kill()
        self.proxy.js_hook = self.proxy.wrench_hook = None
        self.sim.start()
        self.controller.start()
        with self.proxy.cv:
            self.proxy.f_d, self.proxy.rate = 1.0, 0.0
        self.wait(lambda: self.proxy.clock_jumps > jumps, 'the restarted sim')
        self.wait_tracking(within, 'after restarting sim and controller')

    def close(self) -> None:
        for p in (self.controller, self.sim):
            p.stop()  # (SIGCONT first: a case may have left one stopped)
        self.spun.close()

    @property
    def now(self) -> float:
        return self.proxy.now

    # ------------------------------------------------------------- waiting
    def _tails(self) -> str:
        return '\n'.join(p.tail() for p in (self.sim, self.controller))

    def wait(self, predicate: Callable[[], bool], what: str,
             timeout: float = WALL_TIMEOUT) -> None:
        """Wait until ``predicate()`` (evaluated under the proxy's lock) holds."""
        def holds() -> bool:
            with self.proxy.cv:
                return predicate()
        alive = [proc for name, proc in (('sim', self.sim), ('controller', self.controller))
                 if self.expect_alive[name]]
        wait_for(holds, lambda: f'{what}; sim time {self.now:.3f} s', timeout, alive)

    def run_for(self, dt: float) -> float:
        """Let ``dt`` seconds of sim time pass; returns the time reached."""
        t_end = self.now + dt
        self.wait(lambda: self.proxy.now >= t_end, f'sim time {t_end:.3f} s')
        return self.now

    def diag_after(self, t: float, what: str = '', predicate=None,
                   within: float | None = None) -> dict[str, Any]:
        """
        First /diagnostics status stamped at or after ``t`` (and satisfying ``predicate``).

        Arriving within ``within`` s of sim time from now or from ``t`` when that is given.
        """
        found: list[dict[str, Any]] = []
        t_limit = np.inf if within is None else max(t, self.now) + within

        def ready() -> bool:
            if self.proxy.now > t_limit + 0.1:
                return True
            for stamp, d in reversed(self.proxy.diags):
                if stamp < t:
                    break
                if predicate is None or predicate(d):
                    found.append(d)
                    return True
            return False
        self.wait(ready, f'diagnostics after t={t:.3f} s {what}')
        assert found, f'no /diagnostics status {what} within {within} s after t={t:.3f} s'
        return found[0]

    def last_diag(self) -> dict[str, Any]:
        self.wait(lambda: bool(self.proxy.diags), 'a first /diagnostics message')
        return self.proxy.diags[-1][1]

    def force_ok_for(self, window: float) -> bool:
        p = self.proxy
        return p.t_force_last >= p.now - 0.01 and p.t_force_last - p.t_force_bad >= window

    def wait_tracking(self, within: float, what: str, window: float = 0.3,
                      fresh: bool = True) -> dict[str, Any]:
        """
        Force within f_tol of f_d for ``window`` s of sim time, reached within ``within`` s.

        Then a /diagnostics status stamped in that window (and, if ``fresh``, after this call)
        reports mode 'running', in contact.
        """
        t_call = self.now
        t_limit = self.now + within
        self.wait(lambda: self.force_ok_for(window) or self.proxy.now > t_limit,
                  f'force tracking ({what})')
        assert self.force_ok_for(window), (
            f'{what}: |f_n - {self.proxy.f_d}| > {self.proxy.f_tol} N still at '
            f't={self.proxy.t_force_bad:.3f} s, {within} s after t={t_limit - within:.3f} s')
        t_ok = max(self.proxy.t_force_bad, t_call if fresh else -np.inf)
        d = self.diag_after(t_ok, what, within=window + within + 1.5)
        assert d['mode'] == 'running' and d['in_contact'] is True, (what, d)
        return d

    # ------------------------------------------------------------- faults
    def fault(self, duration: float, js: Hook | None = None, wrench: Hook | None = None
              ) -> tuple[float, float]:
        """Play hooks for ``duration`` s of sim time; returns (t0, t1)."""
        t0 = self.now
        self.proxy.js_hook, self.proxy.wrench_hook = js, wrench
        try:
            t1 = self.run_for(duration)
        finally:
            self.proxy.js_hook = self.proxy.wrench_hook = None
        return t0, t1

    def set_limits(self, limits: np.ndarray | None = None, rate: float | None = None) -> None:
        """Tell the effort monitor the limits now in force (after the parameter set)."""
        with self.proxy.cv:
            if limits is not None:
                self.proxy.limits = np.asarray(limits, dtype=float)
            if rate is not None:
                self.proxy.rate, self.proxy.rate_from = rate, self.proxy.now + 0.005

    @contextmanager
    def quick_watchdog(self) -> Iterator[None]:
        """
        Shorten the sim's lockstep watchdog to 0.2 s while a case stops the controller.

        Otherwise the default (2 s) holds: a test process or controller starved for a second by
        the real-time tests beside it slows the run and changes nothing (at 0.2 s, five watchdog
        steps without a command zeroed the effort; docs/results.md section 28).
        """
        assert self.set_params(self.sim_params, lockstep_watchdog=QUICK_WATCHDOG)[0].successful
        try:
            yield
        finally:
            assert self.set_params(self.sim_params,
                                   lockstep_watchdog=LOCKSTEP_WATCHDOG)[0].successful

    # ------------------------------------------------------------- parameters
    def set_params(self, client: AsyncParameterClient, **values) -> list:
        """Set each value on its own (like ``ros2 param set``); one result per value."""
        assert client.wait_for_services(timeout_sec=WALL_TIMEOUT)
        params = [Parameter(k, value=v) for k, v in values.items()]
        return wait_future(client.set_parameters(params), WALL_TIMEOUT).results

    def set_atomically(self, client: AsyncParameterClient, **values):
        assert client.wait_for_services(timeout_sec=WALL_TIMEOUT)
        params = [Parameter(k, value=v) for k, v in values.items()]
        return wait_future(client.set_parameters_atomically(params), WALL_TIMEOUT).result

    def get_params(self, client: AsyncParameterClient, *names: str) -> list[Any]:
        assert client.wait_for_services(timeout_sec=WALL_TIMEOUT)
        values = wait_future(client.get_parameters(list(names)), WALL_TIMEOUT).values
        return [parameter_value_to_python(v) for v in values]

    # ------------------------------------------------------------- cases
    @contextmanager
    def case(self) -> Iterator[dict[str, Any]]:
        """
        Check (1)-(3) of every case around its body.

        The controller is alive and every effort it published meanwhile was finite and within the
        limits and rate limit.
        """
        info = {'violations': len(self.proxy.violations), 'cmds': len(self.proxy.cmds),
                'sim_log': self.sim.log_size(), 't0': self.now}
        yield info
        assert self.controller.alive, 'the controller process died\n' + self._tails()
        new = self.proxy.violations[info['violations']:]
        assert not new, f'{len(new)} bad efforts published, first: {new[:5]}'
        assert len(self.proxy.cmds) > info['cmds'], 'no effort was published during the case'

    def sim_log(self, info: dict[str, Any]) -> str:
        return self.sim.log_since(info['sim_log'])
