"""
Shared helpers of the tests that run over real DDS: processes, domains, spinning, waits.

* :func:`domain_id`: each test module gets its own ROS domain, offset from the base domain
  of the run (``ROS_DOMAIN_ID`` when the run started, 42 by default), so two runs with
  different bases (two checkouts, CI beside a developer) never hear each other. DDS stays
  on this machine (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, set by conftest.py and
  passed to every process).
* :data:`CONTROLLER_MODULE`, :data:`SIM_MODULE`, :data:`RECORDER_MODULE`: what the nodes run.
* :class:`NodeProcess`: a node started as ``python -m MODULE --ros-args ...``, its output
  in a log file, stopped by its pid on every path (SIGINT, then SIGKILL); :func:`freeze`
  stops one with SIGSTOP for a while (the fault), then lets it go on.
* :class:`Spun`: an rclpy context of its own, in a domain, with nodes spun by a background
  executor thread.
* :func:`wait_for`, :func:`wait_future`: wait on a condition with a wall timeout that only
  guards against a hang (no test asserts wall time).
* :func:`parse_diagnostics`: a ``/diagnostics`` status as a dict with typed values;
  :func:`stamp_s`: a message stamp in seconds.

The watchers of a running cell (the true force, /diagnostics, the telemetry), what a clean
run's statuses say and the real-time rig are in :mod:`helpers.watch`.
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
RECORDER_MODULE = 'hybrid_force_controller.ros.programs.recorder_node'
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
    'mujoco_ros': 30, 'dds_profile': 31, 'fault_inputs': 32, 'orientation_ros': 33,
    'paced_timer': 34, 'gateway_mirror': 35,
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
        """
        Spin until close(); an entity destroyed by the test's thread mid-spin is skipped.

        A test that destroys a subscription while this thread builds its wait set meets rclpy's
        InvalidHandle ("destruction was requested") here: the thread used to end, and every
        watcher of this context went deaf (test_gateway, a clean-clone run: three waits of 120 s
        for /diagnostics). The next spin builds the wait set without that entity.
        """
        from rclpy._rclpy_pybind11 import InvalidHandle, RCLError
        from rclpy.executors import ExternalShutdownException
        while self.context.ok():
            try:
                self.executor.spin_once(timeout_sec=0.1)
            except InvalidHandle:
                continue
            except (ExternalShutdownException, RCLError):
                # close() shut the context down: spin_once() woke up and ends here (or, shut
                # down while building its next wait set, failed to build it)
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


def freeze(proc: NodeProcess, seconds: float) -> tuple[float, float]:
    """
    Stop ``proc`` (SIGSTOP) for ``seconds``, then let it go on (SIGCONT).

    The sleep is the fault itself (a frozen process), not a wait on a condition. Returns the
    wall times (``time.time()``, the sims' stamps) of the stop and of the release.
    """
    t_stop = time.time()
    proc.signal(signal.SIGSTOP)
    try:
        time.sleep(seconds)
    finally:
        proc.signal(signal.SIGCONT)
    return t_stop, time.time()


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
