"""
Shared helpers of the tests that run over real DDS.

* :func:`domain_id`: each test module gets its own ROS domain, offset from the base domain
  of the run (``ROS_DOMAIN_ID`` when the run started, 42 by default), so two runs with
  different bases (two checkouts, CI beside a developer) never hear each other. DDS stays
  on this machine (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, set by conftest.py and
  passed to every process).
* :class:`NodeProcess`: a node started as ``python -m MODULE --ros-args ...``, its output
  in a log file, stopped by its pid on every path (SIGINT, then SIGKILL).
* :class:`Spun`: an rclpy context of its own, in a domain, with nodes spun by a background
  executor thread.
* :func:`wait_for`, :func:`wait_future`: wait on a condition with a wall timeout that only
  guards against a hang (no test asserts wall time).
* :func:`parse_diagnostics`: a ``/diagnostics`` status as a dict with typed values;
* :func:`stamp_s`: a message stamp in seconds; :class:`ForceLog`: the true normal force
  (``sim/contact_wrench``) and the latest ``/diagnostics`` of each node, stamped, and
  optionally the controller's ``~/theta_hat`` (stamped on reception, wall clock);
* :class:`RealTimeRig`: the sim (masses 50 % off, its 0.1 s command watchdog) and the
  controller in real time with ``config/params.yaml``, a force log and a parameter client.
"""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time
from typing import Any, Callable, Iterable, Sequence

from hybrid_force_controller.ros.programs.launch import cell_env


ROOT = Path(__file__).resolve().parents[2]  # the repository (this is test/helpers/ros.py)
PARAMS_FILE = ROOT / 'config' / 'params.yaml'
WALL_TIMEOUT = 120.0  # only against hangs
CONTROLLER_MODULE = 'hybrid_force_controller.ros.controller.controller_node'
SIM_MODULE = 'sim_node.sim_node'
CELL_MODULES = {CONTROLLER_MODULE, SIM_MODULE}  # started by node_env(cell=True)

BASE_DOMAIN = int(os.environ.get('ROS_DOMAIN_ID', '42'))
ISOLATED = {'HFC_CELL_DOMAIN_ID': 'auto'}  # node_env(**ISOLATED): the product's default
# one domain per test module (offsets from BASE_DOMAIN); collisions are visible here
_DOMAIN_OFFSETS = {
    'default': 0, 'nodes_params': 1, 'nodes_closed_loop': 2, 'fault_injection': 3,
    'any_arm': 4, 'colcon_build': 5, 'demo': 6, 'recorder': 7, 'realtime': 8,
    'realtime_faults': 9, 'lifecycle': 10, 'namespaces': 11, 'robot_description': 12,
    'shutdown': 13, 'stiffness': 14, 'qos': 15, 'sim_node': 16, 'bench': 17,
    'discipline': 18, 'discipline_refused': 19, 'realtime_stalls': 20, 'sim_watchdog': 21,
    'wrong_inputs': 22, 'path_ros': 23, 'task_interface': 24, 'contact_normal': 25,
    'surface_normal_ros': 26, 'flight_recorder': 27, 'gateway': 28,
    'mujoco_ros': 30, 'dds_profile': 31, 'fault_inputs': 32,
}


def domain_id(name: str) -> int:
    """Return the ROS domain of test module ``name`` in this run (valid Fast DDS ids: 0-232)."""
    return (BASE_DOMAIN + _DOMAIN_OFFSETS[name]) % 233


def node_env(domain: int, cell: bool = False, **extra: str) -> dict[str, str]:
    """
    Environment of a node process: its domain, DDS on localhost, unbuffered logs.

    An observer (a recorder, a program, a script: ``cell`` false) keeps the suite's loopback
    Fast DDS profile (conftest.py); the sim and the controller (``cell``) get the caller's
    settings, shared memory between them, as the programs start them (launch.cell_env).
    """
    base = cell_env() if cell else os.environ
    return dict(base, PYTHONPATH=str(ROOT), ROS_DOMAIN_ID=str(domain),
                ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1',
                RCUTILS_LOGGING_BUFFERED_STREAM='0', **extra)


class NodeProcess:
    """
    One node process; its output goes to a log file that a failure message can show.

    ``params_file`` (default config/params.yaml; ``None`` for none) and ``args`` follow
    ``--ros-args``; ``argv`` goes before it (the executable's own options).
    """

    def __init__(self, module: str, log_path: Path, domain: int, args: Sequence[str] = (),
                 params_file: Path | None = PARAMS_FILE, argv: Sequence[str] = (),
                 env: dict[str, str] | None = None, cwd: Path = ROOT) -> None:
        self.module, self.log_path, self.domain = module, Path(log_path), domain
        self.args, self.params_file, self.argv = list(args), params_file, list(argv)
        self.env, self.cwd = env, cwd
        self.proc: subprocess.Popen | None = None
        self.starts = 0
        self.command_override: list[str] | None = None  # an installed executable instead

    @property
    def command(self) -> list[str]:
        if self.command_override is not None:
            return [*self.command_override, *self.argv, '--ros-args', *self.args]
        files = [] if self.params_file is None else ['--params-file', str(self.params_file)]
        return [sys.executable, '-m', self.module, *self.argv, '--ros-args', *files, *self.args]

    def start(self) -> 'NodeProcess':
        cmd = self.command
        self.starts += 1
        with open(self.log_path, 'a') as log:
            log.write(f'\n===== start {self.starts}: {" ".join(cmd)}\n')
            log.flush()
            env = self.env or node_env(self.domain, cell=self.module in CELL_MODULES)
            self.proc = subprocess.Popen(cmd, cwd=self.cwd, env=env,
                                         stdout=log, stderr=subprocess.STDOUT)
        return self

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    @property
    def alive(self) -> bool:
        return self.proc is not None and self.proc.poll() is None

    @property
    def returncode(self) -> int | None:
        return None if self.proc is None else self.proc.poll()

    def signal(self, sig: int) -> None:
        if self.alive:
            self.proc.send_signal(sig)

    def kill(self) -> None:
        """SIGCONT (in case it was stopped), SIGKILL, and reap."""
        if self.alive:
            self.proc.send_signal(signal.SIGCONT)
            self.proc.kill()
        if self.proc is not None:
            self.proc.wait(30)

    def refused_at_start_up(self, timeout: float = 60.0) -> str:
        """
        Start, wait for the process to end by itself, and return its log.

        For a node whose configuration is invalid: it must exit 1 on its own (asserted).
        """
        self.start()
        try:
            self.proc.wait(timeout)
        finally:
            self.stop()
        assert self.returncode == 1, self.tail()
        return self.log_since()

    def stop(self, timeout: float = 10.0) -> int | None:
        """
        SIGINT (clean shutdown); SIGKILL if it does not exit within ``timeout``.

        Returns the exit code.
        """
        if self.alive:
            self.proc.send_signal(signal.SIGCONT)
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.kill()
        return self.returncode

    def log_size(self) -> int:
        return self.log_path.stat().st_size if self.log_path.exists() else 0

    def log_since(self, offset: int = 0) -> str:
        if not self.log_path.exists():
            return ''
        with open(self.log_path, errors='replace') as f:
            f.seek(offset)
            return f.read()

    def tail(self, chars: int = 2500) -> str:
        start = max(0, self.log_size() - chars)
        return f'--- {self.log_path.name} (tail)\n{self.log_since(start)}'

    def __enter__(self) -> 'NodeProcess':
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()


class Spun:
    """An rclpy context in ``domain`` whose nodes a background executor thread spins."""

    def __init__(self, domain: int, args: list[str] | None = None) -> None:
        import rclpy
        from rclpy.context import Context
        from rclpy.executors import SingleThreadedExecutor
        self.context = Context()
        rclpy.init(args=args, context=self.context, domain_id=domain)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.nodes: list[Any] = []
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        from rclpy._rclpy_pybind11 import RCLError
        from rclpy.executors import ExternalShutdownException
        try:
            self.executor.spin()
        except (ExternalShutdownException, RCLError):
            # close() shut the context down: spin() woke up and ends here (or, shut down while
            # building its next wait set, failed to build it)
            if self.context.ok():
                raise

    def add(self, node: Any) -> Any:
        """Spin ``node`` (created with ``context=self.context``); returns it."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def node(self, name: str, namespace: str = '') -> Any:
        """Create a plain node in this context (in ``namespace``), spun."""
        import rclpy
        return self.add(rclpy.create_node(name, context=self.context, namespace=namespace))

    def close(self) -> None:
        """
        Stop the spin thread, then destroy.

        The context goes first: it wakes spin(), which ends before anything is destroyed
        (``executor.shutdown()`` first destroyed its guard condition while the spin thread could
        still be adding it to a wait set: an InvalidHandle in that thread).
        """
        import rclpy
        rclpy.try_shutdown(context=self.context)
        self.thread.join(WALL_TIMEOUT)
        self.executor.shutdown(timeout_sec=WALL_TIMEOUT)
        for node in self.nodes:
            node.destroy_node()

    def __enter__(self) -> 'Spun':
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def wait_for(predicate: Callable[[], bool], what: str | Callable[[], str],
             timeout: float = WALL_TIMEOUT, alive: Iterable[NodeProcess] = (),
             poll: float = 0.01) -> None:
    """
    Wait until ``predicate()`` holds.

    Fail (with the processes' log tails) when one of ``alive`` exits or after ``timeout`` s of wall
    time (a guard against hangs only). ``what`` names the condition (a callable: evaluated when
    the wait fails, for a message that says where things stood then).
    """
    procs = list(alive)
    deadline = time.monotonic() + timeout
    pause = threading.Event()

    def said() -> str:
        return what() if callable(what) else what
    while not predicate():
        for p in procs:
            if not p.alive:
                raise AssertionError(f'{p.module} exited ({p.returncode}) while waiting for '
                                     f'{said()}\n{p.tail()}')
        if time.monotonic() > deadline:
            raise AssertionError(f'timed out waiting for {said()}\n'
                                 + '\n'.join(p.tail() for p in procs))
        pause.wait(poll)


def wait_future(future: Any, timeout: float = WALL_TIMEOUT) -> Any:
    """Return the result of a future that a background executor completes (within ``timeout``)."""
    done = threading.Event()
    future.add_done_callback(lambda _: done.set())
    assert done.wait(timeout), 'no answer from the service'
    return future.result()


def parse_diagnostics(msg: Any) -> dict[str, Any]:
    """
    Parse the first status of a DiagnosticArray.

    ``level``, ``message``, ``name`` and every key-value, with ints, floats and booleans converted.
    """
    status = msg.status[0]
    level = status.level
    values: dict[str, Any] = {
        'level': int.from_bytes(level, 'little') if isinstance(level, bytes) else int(level),
        'message': status.message, 'name': status.name}
    for kv in status.values:
        v: Any = kv.value
        if v in ('True', 'False'):
            v = v == 'True'
        else:
            for kind in (int, float):
                try:
                    v = kind(v)
                    break
                except ValueError:
                    pass
        values[kv.key] = v
    return values


def stamp_s(stamp: Any) -> float:
    """Return a ``builtin_interfaces/Time`` in seconds."""
    return stamp.sec + 1e-9 * stamp.nanosec


class ForceLog:
    """
    The true normal force ``n . f`` of ``sim/contact_wrench`` and the latest diagnostics.

    Spun on a :class:`Spun` context: ``ForceLog(spun)``; stamps in seconds.
    """

    def __init__(self, spun: Spun, n_W: Sequence[float] = (0.0, -1.0, 0.0),
                 name: str = 'force_log', theta_topic: str | None = None) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import WrenchStamped
        from rclpy.qos import QoSProfile
        from std_msgs.msg import Float64MultiArray
        self.n_W = tuple(float(x) for x in n_W)
        self.lock = threading.Lock()
        self.force: list[tuple[float, float]] = []
        self.theta: list[tuple[float, tuple[float, ...]]] = []
        self.diags: dict[str, dict[str, Any]] = {}
        self.node = spun.node(name)
        q = QoSProfile(depth=1000)
        self.node.create_subscription(WrenchStamped, 'sim/contact_wrench', self._on_force, q)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, q)
        if theta_topic:
            self.node.create_subscription(Float64MultiArray, theta_topic, self._on_theta, q)

    def _on_theta(self, msg: Any) -> None:
        with self.lock:
            self.theta.append((time.time(), tuple(msg.data)))

    def thetas(self) -> tuple[Any, Any]:
        """Return the reception times (wall clock, s) and theta_hat rows, as numpy arrays."""
        import numpy as np
        with self.lock:
            rows = list(self.theta)
        return np.array([t for t, _ in rows]), np.array([th for _, th in rows])

    def _on_force(self, msg: Any) -> None:
        f = msg.wrench.force
        n = self.n_W
        with self.lock:
            self.force.append((stamp_s(msg.header.stamp), n[0] * f.x + n[1] * f.y + n[2] * f.z))

    def _on_diag(self, msg: Any) -> None:
        d = parse_diagnostics(msg)
        d['received_s'] = time.monotonic()
        with self.lock:
            self.diags[msg.status[0].hardware_id] = d

    def diag(self, hardware_id: str) -> dict[str, Any]:
        """Return the latest /diagnostics values of ``hardware_id`` ({} before any)."""
        with self.lock:
            return dict(self.diags.get(hardware_id, {}))

    def fresh_diag(self, hardware_id: str, alive: Iterable[NodeProcess] = ()) -> dict[str, Any]:
        """Wait for a status of ``hardware_id`` newer than now and return it."""
        t = time.monotonic()
        wait_for(lambda: self.diag(hardware_id).get('received_s', 0.0) > t,
                 f'a new /diagnostics status of {hardware_id}', alive=alive)
        return self.diag(hardware_id)

    def latest_t(self) -> float:
        """Return the stamp of the newest force sample, s (0 before any)."""
        with self.lock:
            return self.force[-1][0] if self.force else 0.0

    def forces(self, t0: float = -float('inf'), t1: float = float('inf')) -> tuple[Any, Any]:
        """Return the stamps and forces in [t0, t1] as two numpy arrays."""
        import numpy as np
        with self.lock:
            pairs = [(t, f) for t, f in self.force if t0 <= t <= t1]
        return (np.array([t for t, _ in pairs]), np.array([f for _, f in pairs]))


MASSES_OFF = ('-p', 'masses:=[0.65, 1.35]')


class RealTimeRig:
    """
    Sim (masses 50 % off, ``command_timeout`` 0.1 s) and controller in real time.

    With a :class:`ForceLog` (and theta_hat) and a parameter client of the controller;
    ``ctrl_prefix`` runs the controller under a wrapper (``setpriv`` ...); ``isolated``: on the
    cell domain behind the gateway (the product's default; the suite's is ``off``). Stopped by
    pid.
    """

    def __init__(self, tmp_path: Path, domain: int, ctrl_prefix: Sequence[str] = (),
                 sim_args: Sequence[str] = MASSES_OFF, ctrl_args: Sequence[str] = (),
                 isolated: bool = False) -> None:
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
        self.log = ForceLog(self.spun, theta_topic='hybrid_force_controller/theta_hat')
        self.params = AsyncParameterClient(self.log.node, 'hybrid_force_controller')
        self.t_touch = 0.0

    def start(self) -> 'RealTimeRig':
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

    def settled(self, f_d: float, hold_s: float = 0.3, tol: float = 0.1) -> bool:
        """Say whether the last ``hold_s`` of true force is within ``tol`` of ``f_d``."""
        import numpy as np
        t = self.log.latest_t()
        _, f = self.log.forces(t - hold_s, t)
        return f.size > 10 and bool(np.all(np.abs(f - f_d) < tol))
