"""
Watching a running cell over DDS, and the real-time rig the tests start.

* :class:`ForceLog`: the true normal force ``n . f`` of ``sim/contact_wrench`` and every
  ``/diagnostics`` status of each node, stamped; on request ``~/x`` and ``~/x_desired``, the
  efforts, the joint states, ``/clock`` and ``~/theta_hat``. Callbacks only collect: the tests
  assert on what was collected, never in a callback (a failure there would only show as a
  timeout).
* :func:`assert_clean_run`: what the statuses of a clean run say (no exception in a callback,
  no refused input, no safe mode; in real time the last two only where the controller's own
  measures say the machine kept the loop, :func:`loop_kept_up`);
* :class:`RealTimeRig`: the sim (masses 50 % off, its 0.1 s command watchdog) and the
  controller in real time with ``config/params.yaml``, a force log and parameter clients.
"""
from __future__ import annotations

import bisect
from pathlib import Path
import threading
import time
from typing import Any, Iterable, Sequence

from helpers.figures import current_test, report_figure
from helpers.ros import (CONTROLLER_MODULE, ISOLATED, node_env, NodeProcess, parse_diagnostics,
                         SIM_MODULE, Spun, stamp_s, wait_for)
from helpers.witness import stalls_text
import numpy as np


MAX_JOINT_STATES = 100000  # kept of the joint states (100 s at 1 kHz)


class ForceLog:
    """
    The true normal force, the nodes' /diagnostics and, on request, the telemetry; stamped.

    Spun on a :class:`~helpers.ros.Spun` context: ``ForceLog(spun)``, in ``namespace`` (its
    topics are relative, but /diagnostics). Times are message stamps in seconds; a status is
    kept under its node's ``hardware_id`` and its fully qualified name (``/arm1/sim``), with
    ``stamp_s`` (the node's clock when it reported) and ``received_s`` (this process's
    monotonic clock when it came).
    """

    def __init__(self, spun: Spun, n_W: Sequence[float] = (0.0, -1.0, 0.0),
                 name: str = 'force_log', theta_topic: str | None = None, namespace: str = '',
                 points: bool = False, efforts: bool = False, joint_states: bool = False,
                 clock: bool = False) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PointStamped, WrenchStamped
        from rclpy.qos import QoSProfile
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray
        self.n_W = np.array([float(x) for x in n_W])
        self.lock = threading.Lock()
        self.f_t: list[float] = []  # stamps of the true force, s, and the force along n, N
        self.f_n: list[float] = []
        self._in_order = True  # f_t ascending (a restarted sim's clock may break it)
        self.theta: list[tuple[float, tuple[float, ...]]] = []
        self.diags: dict[str, dict[str, Any]] = {}
        self.history: dict[str, list[dict[str, Any]]] = {}
        self.x: dict[float, np.ndarray] = {}
        self.x_d: dict[float, np.ndarray] = {}
        self.efforts: list[tuple[float, float]] = []  # (latest force stamp, largest |effort|)
        self.js: list[tuple[float, np.ndarray]] = []
        self.clock = 0.0
        self.node = spun.node(name, namespace)
        q = QoSProfile(depth=1000)
        sub = self.node.create_subscription
        sub(WrenchStamped, 'sim/contact_wrench', self._on_force, q)
        sub(DiagnosticArray, '/diagnostics', self._on_diag, q)
        if theta_topic:
            sub(Float64MultiArray, theta_topic, self._on_theta, q)
        if points:
            sub(PointStamped, 'hybrid_force_controller/x', lambda m: self._point(self.x, m), q)
            sub(PointStamped, 'hybrid_force_controller/x_desired',
                lambda m: self._point(self.x_d, m), q)
        if efforts:
            sub(Float64MultiArray, 'effort_controller/commands', self._on_effort, q)
        if joint_states:
            sub(JointState, 'joint_states', self._on_js, q)
        if clock:
            sub(Clock, '/clock', self._on_clock, q)

    # ------------------------------------------------------------------ callbacks: collect
    def _on_force(self, msg: Any) -> None:
        f, t = msg.wrench.force, stamp_s(msg.header.stamp)
        with self.lock:
            self._in_order = self._in_order and (not self.f_t or t >= self.f_t[-1])
            self.f_t.append(t)
            self.f_n.append(float(self.n_W @ [f.x, f.y, f.z]))

    def _on_diag(self, msg: Any) -> None:
        d = parse_diagnostics(msg)
        d['received_s'] = time.monotonic()
        d['stamp_s'] = stamp_s(msg.header.stamp)  # the publisher's clock when it reported
        status = msg.status[0]
        with self.lock:
            for key in {status.hardware_id, status.name.split(':')[0]}:
                self.diags[key] = d
                self.history.setdefault(key, []).append(d)

    def _on_theta(self, msg: Any) -> None:
        with self.lock:
            self.theta.append((time.time(), tuple(msg.data)))

    def _point(self, store: dict, msg: Any) -> None:
        with self.lock:
            store[stamp_s(msg.header.stamp)] = np.array([msg.point.x, msg.point.y, msg.point.z])

    def _on_effort(self, msg: Any) -> None:
        peak = float(np.max(np.abs(msg.data))) if len(msg.data) else 0.0
        with self.lock:
            self.efforts.append((self.f_t[-1] if self.f_t else 0.0, peak))

    def _on_js(self, msg: Any) -> None:
        with self.lock:
            if len(self.js) < MAX_JOINT_STATES:
                self.js.append((stamp_s(msg.header.stamp), np.array(msg.position)))

    def _on_clock(self, msg: Any) -> None:
        with self.lock:
            self.clock = max(self.clock, stamp_s(msg.clock))

    # ------------------------------------------------------------------ readers
    def diag(self, node: str) -> dict[str, Any]:
        """Return the latest status of ``node`` (hardware_id or full name; {} before any)."""
        with self.lock:
            return dict(self.diags.get(node, {}))

    def fresh_diag(self, node: str, alive: Iterable[NodeProcess] = ()) -> dict[str, Any]:
        """Wait for a status of ``node`` newer than now and return it."""
        t = time.monotonic()
        wait_for(lambda: self.diag(node).get('received_s', 0.0) > t,
                 f'a new /diagnostics status of {node}', alive=alive)
        return self.diag(node)

    def statuses(self, node: str, t0: float = -np.inf, t1: float = np.inf) -> list[dict]:
        """Return the statuses of ``node`` stamped in [t0, t1], oldest first."""
        with self.lock:
            return [d for d in self.history.get(node, ()) if t0 <= d['stamp_s'] <= t1]

    def latest_t(self) -> float:
        """Return the stamp of the newest force sample, s (0 before any)."""
        with self.lock:
            return self.f_t[-1] if self.f_t else 0.0

    def forces(self, t0: float = -np.inf, t1: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
        """Return the stamps and forces in [t0, t1] as two numpy arrays."""
        with self.lock:  # cheap when polled: a bisection of the stamps, not a pass over them
            if self._in_order:
                i, j = bisect.bisect_left(self.f_t, t0), bisect.bisect_right(self.f_t, t1)
                return np.array(self.f_t[i:j]), np.array(self.f_n[i:j])
            pairs = [(t, f) for t, f in zip(self.f_t, self.f_n) if t0 <= t <= t1]
        return np.array([t for t, _ in pairs]), np.array([f for _, f in pairs])

    def command_after(self, t: float, k: int = 1) -> float:
        """Return the force stamp when the ``k``-th command after stamp ``t`` came (inf: none)."""
        with self.lock:
            stamps = [s for s, _ in self.efforts if s > t]
        return stamps[k - 1] if len(stamps) >= k else np.inf

    def recent(self, k: int) -> np.ndarray:
        """Return the last ``k`` forces (fewer before there are ``k``)."""
        with self.lock:
            return np.array(self.f_n[-k:])

    def thetas(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the reception times (wall clock, s) and theta_hat rows, as numpy arrays."""
        with self.lock:
            rows = list(self.theta)
        return np.array([t for t, _ in rows]), np.array([th for _, th in rows])

    def tangential_rms(self, t0: float, t1: float) -> tuple[float, int]:
        """
        Return the RMS of ``x - x_d`` across n over stamps in [t0, t1], and how many pairs.

        Pairs are ``~/x`` and ``~/x_desired`` of the same stamp (NaN when none).
        """
        with self.lock:
            pairs = [(x, self.x_d[t]) for t, x in self.x.items()
                     if t0 <= t <= t1 and t in self.x_d]
        if not pairs:
            return float('nan'), 0
        across = np.eye(3) - np.outer(self.n_W, self.n_W)
        e = np.array([across @ (x - x_d) for x, x_d in pairs])
        return float(np.sqrt(np.mean(np.sum(np.square(e), axis=1)))), len(pairs)

    def max_effort(self, t0: float = -np.inf, t1: float = np.inf) -> float:
        """Return the largest |effort| commanded while the force stamps were in [t0, t1]."""
        with self.lock:
            peaks = [p for t, p in self.efforts if t0 <= t <= t1]
        return max(peaks, default=0.0)

    def joint_positions(self) -> np.ndarray:
        """Return every joint position received so far, one row a message."""
        with self.lock:
            return np.array([q for _, q in self.js])


# the runtime's counters of the inputs it refused, by the callback that refused them: such a
# refusal is counted as that callback's error too (an InputError), and is no failure of the code
REFUSED = {'joint_states': ('joint_state_dropped', 'joint_state_implausible',
                            'joint_state_clock_implausible'),
           'wrench': ('wrench_dropped', 'wrench_implausible', 'wrench_clock_implausible')}


def callback_errors(status: dict[str, Any]) -> dict[str, int]:
    """Return the callback errors a controller's status counts, by callback ({} when none)."""
    return {k.removeprefix('callback_errors_'): int(v) for k, v in status.items()
            if k.startswith('callback_errors_') and v}


def callback_exceptions(status: dict[str, Any]) -> dict[str, int]:
    """Return the callback errors that are not refused inputs (exceptions: the code's own)."""
    out = {}
    for kind, n in callback_errors(status).items():
        n -= sum(int(status.get(counter, 0)) for counter in REFUSED.get(kind, ()))
        if n:
            out[kind] = n
    return out


def loop_kept_up(statuses: Iterable[dict[str, Any]]) -> str:
    """
    Say why the controller's own measures say this machine did not keep its loop ('' if it did).

    Any status of the run with the input-to-command delay (p99) beyond the gains' delay margin
    (the loop is then not the one the gains were checked for; the controller warns from half of
    it) or a stall longer than state_timeout. Then refused inputs and safe modes are this
    machine's speed, not the code's behaviour.
    """
    for d in statuses:
        delay, margin = float(d.get('delay_p99_ms', 'nan')), float(d.get('delay_margin_ms', 'inf'))
        if delay > margin:
            return f'loop delay p99 {delay:.4g} ms > the delay margin {margin:.4g} ms'
        if d.get('episodes_stall', 0):
            return f"{d['episodes_stall']} stalls of the loop longer than state_timeout"
    return ''


def startup_clock_refusals(ctrl: dict[str, Any]) -> dict[str, int]:
    """
    Return, per input, the stamps refused, all of them in its clock's first second.

    Keyed ``joint_states`` and ``wrench``; only the streams whose ``*_clock_implausible``
    count is non-zero and equal to their ``*_clock_startup_refusals``: the middleware's
    start-up (sender_clock.py). While the cell's participants meet, one first send can sleep
    333 ms: a stream's first sample late costs one refused stamp and a relearn (s51h), the
    samples held up behind it one more per ``state_timeout`` of backlog (s51k: 3 and 3), and a
    sample of the other stream held up by it one (s52b). A clock that steps later refuses
    about 200 stamps after the first second: never excused.
    """
    out = {}
    for kind, stream in (('joint_states', 'joint_state'), ('wrench', 'wrench')):
        n = int(ctrl.get(f'{stream}_clock_implausible', 0))
        if n and n == int(ctrl.get(f'{stream}_clock_startup_refusals', 0)):
            out[kind] = n
    return out


def assert_clean_run(ctrl: dict[str, Any], sim: dict[str, Any] | None = None,
                     safe_mode_entries: int | None = 0,
                     run: Iterable[dict[str, Any]] | None = None) -> None:
    """
    Assert what the statuses of a clean run say: nothing failed, nothing unexpected happened.

    Always: the controller's callbacks raised no exception (``callback_errors_*`` beyond the
    inputs the runtime refused, counted and swallowed by the callbacks' guards), no control
    error; the sim's callbacks no error. And no input refused, ``safe_mode_entries`` safe-mode
    entries (None: not checked, where a test's own fault may cause one) - in real time (``run``:
    the controller's statuses over the run) only when the controller's own measures say this
    machine kept the loop (:func:`loop_kept_up`) and the machine itself did not stall
    (:mod:`helpers.witness`); else those counts are printed and handed on
    (helpers.figures.report_figure), not asserted: they are then this machine's speed. A
    stream's refused stamps that were all refused in its clock's first second (as many
    ``*_clock_implausible`` as ``*_clock_startup_refusals``, and nothing else refused on it)
    are no refused input: the middleware's start-up (:func:`startup_clock_refusals`).
    """
    problems = []
    if callback_exceptions(ctrl):
        problems.append(f'exceptions in callbacks {callback_exceptions(ctrl)}')
    if ctrl.get('control_errors', 0):
        problems.append(f"{ctrl['control_errors']} control errors")
    if sim is not None and sim.get('errors', 0):
        problems.append(f"{sim['errors']} errors in the sim's callbacks")
    refused = {k: v for k, v in callback_errors(ctrl).items() if k in REFUSED}
    for kind, n in startup_clock_refusals(ctrl).items():
        if refused.get(kind, 0) == n:
            print(f"{kind}: {n} stamp(s) refused, all in its clock's first second")
            del refused[kind]
    safe = ctrl.get('safe_mode_entries')
    slow = '' if run is None else (loop_kept_up(run) or stalls_text())
    if slow:
        print(f'not asserted ({slow}): refused inputs {refused}, {safe} safe-mode entries')
        report_figure(current_test(), machine_did_not_keep_up=slow, refused_inputs=refused,
                      safe_mode_entries=safe)
    else:
        if refused:
            problems.append(f'inputs refused {refused} ({ctrl.get("last_input_fault")!r})')
        if safe_mode_entries is not None and safe != safe_mode_entries:
            problems.append(f'safe_mode_entries {safe}, expected {safe_mode_entries} '
                            f'(last: {ctrl.get("last_safe_reason")!r})')
    assert not problems, '; '.join(problems) + f'\ncontroller: {ctrl}\nsim: {sim}'


MASSES_OFF = ('-p', 'masses:=[0.65, 1.35]')  # URDF: 1.3, 0.9 (each 50 % off)


class RealTimeRig:
    """
    Sim (masses 50 % off, ``command_timeout`` 0.1 s) and controller in real time.

    With a :class:`ForceLog` (and theta_hat; ``watch``: more of it, see its arguments) and
    parameter clients of the controller (``params``) and the sim (``sim_params``);
    ``ctrl_prefix`` runs the controller under a wrapper (``setpriv`` ...); ``isolated``: on the
    cell domain behind the gateway (the product's default; the suite's is ``off``). Processes
    appended to ``procs`` before :meth:`start` start and stop with the cell. Stopped by pid.
    """

    def __init__(self, tmp_path: Path, domain: int, ctrl_prefix: Sequence[str] = (),
                 sim_args: Sequence[str] = MASSES_OFF, ctrl_args: Sequence[str] = (),
                 isolated: bool = False, **watch: bool) -> None:
        from rclpy.parameter_client import AsyncParameterClient
        env = node_env(domain, cell=True, **ISOLATED) if isolated else None
        self.sim = NodeProcess(SIM_MODULE, tmp_path / 'sim.log', domain, list(sim_args),
                               env=env)
        self.ctrl = NodeProcess(CONTROLLER_MODULE, tmp_path / 'controller.log', domain,
                                list(ctrl_args), env=env)
        if ctrl_prefix:
            self.ctrl.command_override = [*ctrl_prefix, *self.ctrl.command[:3]]
            self.ctrl.args = ['--params-file', str(self.ctrl.params_file)]
        self.procs = [self.sim, self.ctrl]
        self.spun = Spun(domain)
        self.log = ForceLog(self.spun, theta_topic='hybrid_force_controller/theta_hat', **watch)
        self.params = AsyncParameterClient(self.log.node, 'hybrid_force_controller')
        self.sim_params = AsyncParameterClient(self.log.node, 'sim')
        self.t_touch = 0.0

    def start(self) -> 'RealTimeRig':
        """Start the processes and wait for the tool to touch the surface."""
        from hybrid_force_controller.core.runtime.contact import in_contact
        for p in self.procs:
            p.start()
        wait_for(lambda: self.log.latest_t() > 0.0 and in_contact(self.log.forces()[1][-1]),
                 'the tool to touch the surface', alive=self.procs)
        self.t_touch = self.log.latest_t()
        return self

    def close(self) -> None:
        for p in self.procs:
            p.stop()
        self.spun.close()

    def tails(self, chars: int = 1500) -> str:
        """Return the end of each process's log, for failure messages."""
        return '\n'.join(p.tail(chars) for p in self.procs)

    def settled(self, f_d: float, hold_s: float = 0.3, tol: float = 0.1) -> bool:
        """Say whether the true force of the last ``hold_s`` is within ``tol`` of ``f_d``."""
        t = self.log.latest_t()
        _, f = self.log.forces(t - hold_s, t)
        return f.size > 10 and bool(np.all(np.abs(f - f_d) < tol))
