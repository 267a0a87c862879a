"""
The lab's node processes and their reports: start and stop them by pid, read /diagnostics.

Shared by the instruments (bench, multi_arm, wrong_inputs); depends on no instrument.
"""
from __future__ import annotations

import os
from pathlib import Path
import signal
import subprocess
import sys
import threading
import time
from typing import Any, Callable, Sequence

import numpy as np

from .tracking import TrackingMeter
from ..programs.launch import PKG

__all__ = ['Diagnostics', 'child_pids', 'start_node', 'stop_nodes', 'wait_new_report',
           'WARM_UP_TIMEOUT_S']

WARM_UP_TIMEOUT_S = 90.0


def wait_new_report(get: Callable[[str], tuple[float, dict[str, str]]], name: str,
                    after: float, timeout: float = 10.0) -> dict[str, str]:
    """
    Wait for a /diagnostics report of ``name`` received after ``after`` (monotonic s).

    ``get(name)`` returns (reception time, values) of the newest report. Raises TimeoutError.
    """
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        t, values = get(name)
        if t > after:
            return values
        time.sleep(0.05)
    raise TimeoutError(f'no /diagnostics from {name} within {timeout} s')


class Diagnostics:
    """Latest /diagnostics values per hardware_id, in a background-spun context."""

    def __init__(self, domain: int, n_W: Sequence[float] = (0.0, -1.0, 0.0),
                 f_d: float = 1.0) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from ..common.runner import make_executor
        self.latest: dict[str, dict[str, str]] = {}
        self.received: dict[str, float] = {}
        self.lock = threading.Lock()
        self.context = rclpy.Context()
        from rclpy.signals import SignalHandlerOptions
        rclpy.init(context=self.context, domain_id=domain,  # Ctrl-C: KeyboardInterrupt
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('ros_bench', context=self.context)
        from rclpy.parameter_client import AsyncParameterClient
        from std_msgs.msg import Float64MultiArray
        from .bare_node import TOPIC_BARE_COMMANDS
        from ..common.qos import COMMAND_QOS
        self.sim_history: list[tuple[float, dict[str, str]]] = []
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 10)
        # the bare node's commands have a subscriber, as the controller's have the sim
        self.node.create_subscription(Float64MultiArray, TOPIC_BARE_COMMANDS, lambda m: None,
                                      COMMAND_QOS, raw=True)
        self.tracking = TrackingMeter(self.node, np.array(n_W, dtype=float), f_d)
        self.params = AsyncParameterClient(self.node, PKG)
        self.executor = make_executor('single_threaded', self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self) -> None:
        from rclpy._rclpy_pybind11 import RCLError
        from rclpy.executors import ExternalShutdownException
        try:
            self.executor.spin()
        except (ExternalShutdownException, RCLError):  # close() shut the context down
            pass

    def _on_diag(self, msg: Any) -> None:
        for st in msg.status:
            values = {kv.key: kv.value for kv in st.values}
            with self.lock:
                self.latest[st.hardware_id] = values
                self.received[st.hardware_id] = time.monotonic()
                if st.hardware_id == 'sim':
                    self.sim_history.append((time.monotonic(), values))

    def sim_reports(self, first: dict[str, str], last: dict[str, str]) -> list[dict[str, str]]:
        """Return the sim's reports after ``first`` up to ``last``."""
        with self.lock:
            reports = [v for _, v in self.sim_history]
        ids = [id(r) for r in reports]
        i, j = ids.index(id(first)), ids.index(id(last))
        return reports[i + 1:j + 1]

    def get(self, hardware_id: str) -> tuple[float, dict[str, str]]:
        with self.lock:
            return self.received.get(hardware_id, 0.0), self.latest.get(hardware_id, {})

    def wait_new(self, hardware_id: str, after: float, timeout: float = 10.0) -> dict[str, str]:
        return wait_new_report(self.get, hardware_id, after, timeout)

    def close(self) -> None:
        import rclpy  # the context first: spin() ends before anything is destroyed
        rclpy.try_shutdown(context=self.context)
        self.thread.join(5.0)
        self.executor.shutdown(timeout_sec=5.0)
        self.node.destroy_node()


def start_node(name: str, argv: list[str], env: dict[str, str], log_dir: Path,
               prefix: Sequence[str] = ()) -> subprocess.Popen:
    """Start ``python -m argv`` (after ``prefix``), its output in ``log_dir/name.log``."""
    with open(log_dir / f'{name}.log', 'wb') as log:
        return subprocess.Popen([*prefix, sys.executable, '-m', *argv], env=env, stdout=log,
                                stderr=subprocess.STDOUT)


def stop_nodes(procs: dict[str, subprocess.Popen]) -> None:
    """
    SIGINT each process by pid, then SIGKILL what is left; then any other child of ours.

    A Ctrl-C that lands while a node is being started (inside ``Popen``, or before its
    ``procs[...] =``) leaves a child that ``procs`` does not hold: it ran on after the bench
    had ended (seen once in CI). Those are found among this process's children and stopped
    the same way.
    """
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(2)
    for p in procs.values():
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
    known = {p.pid for p in procs.values()}
    _stop_pids([pid for pid in child_pids(os.getpid()) if pid not in known])


def child_pids(pid: int) -> list[int]:
    """Return the pids of ``pid``'s living children (from /proc)."""
    out = []
    for entry in Path('/proc').iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / 'stat').read_text().rsplit(')', 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid and fields[0] != 'Z':
                out.append(int(entry.name))
    return out


def _stop_pids(pids: list[int], timeout_s: float = 20.0) -> None:
    """SIGINT ``pids``, reap them; SIGKILL those alive after ``timeout_s``."""
    for pid in pids:
        try:
            os.kill(pid, signal.SIGINT)
        except ProcessLookupError:
            pass
    deadline = time.monotonic() + timeout_s
    for pid in pids:
        while time.monotonic() < deadline:
            try:
                if os.waitpid(pid, os.WNOHANG)[0]:
                    break
            except ChildProcessError:
                break
            time.sleep(0.05)
        else:
            try:
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
            except (ProcessLookupError, ChildProcessError):
                pass
