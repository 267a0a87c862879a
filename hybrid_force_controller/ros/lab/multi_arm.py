"""
``bench --ros --arms N``: N sim + controller pairs side by side, each in its own namespace.

The dual-arm cell a user builds with namespaces (``-r __ns:=/arm1`` ...): every pair runs the
same scenario (the config files of ``--arm``/``--physics``, as ``bench --ros``) in real time in
one ROS domain, with one bare node (on the first arm's inputs) as the yardstick. Over
``--ros-duration`` s after the warm-up it reports per arm the commands per second that reached
the plant (the sim's own count over its own time), the sim's command timeouts, the tracking
(ros/lab/tracking.py: RMS tangential position and true-force errors, contact lost) and
the CPU of each process (% of one core), and each controller's CPU over the bare node's.
"""
from __future__ import annotations

import os
from pathlib import Path
import tempfile
import threading
import time
from typing import Any, Sequence

import numpy as np

from .cell_processes import start_node, stop_nodes, wait_new_report
from .load import CpuMeter
from ..programs.launch import cell_env

__all__ = ['multi_arm_figures']

WARM_UP_TIMEOUT_S = 120.0


class _Watcher:
    """Every arm's /diagnostics (by the node's full name) and tracking, spun in the background."""

    def __init__(self, domain: int, namespaces: Sequence[str], n_W: np.ndarray, f_d: float):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.signals import SignalHandlerOptions
        from .tracking import TrackingMeter
        from ..common.runner import make_executor
        self.lock = threading.Lock()
        self.latest: dict[str, tuple[float, dict[str, str]]] = {}
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.executor = make_executor('single_threaded', self.context)
        self.nodes = [rclpy.create_node('multi_arm_bench', context=self.context)]
        self.nodes[0].create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 50)
        self.tracking = {}
        for ns in namespaces:
            node = rclpy.create_node('tracking', namespace=ns, context=self.context)
            self.tracking[ns] = TrackingMeter(node, n_W, f_d)
            self.nodes.append(node)
        for node in self.nodes:
            self.executor.add_node(node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on_diag(self, msg: Any) -> None:
        for st in msg.status:
            name = st.name.split(':')[0]  # the node's fully qualified name
            with self.lock:
                self.latest[name] = (time.monotonic(), {kv.key: kv.value for kv in st.values})

    def get(self, name: str) -> tuple[float, dict[str, str]]:
        with self.lock:
            return self.latest.get(name, (0.0, {}))

    def wait_new(self, name: str, timeout: float = 10.0) -> dict[str, str]:
        return wait_new_report(self.get, name, time.monotonic(), timeout)

    def close(self) -> None:
        import rclpy
        self.executor.shutdown(timeout_sec=5.0)
        for node in self.nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self.thread.join(5.0)


def _launch(arms: int, ros_args: Sequence[str], sim_args: Sequence[str],
            env: dict[str, str], log_dir: Path, procs: dict) -> list[str]:
    """Start the pairs (and the bare node) into ``procs``; return the namespaces."""
    from ..programs.launch import PKG
    namespaces = [f'/arm{k + 1}' for k in range(arms)]
    for ns in namespaces:
        remap = ['-r', f'__ns:={ns}']
        procs[f'sim{ns}'] = start_node(
            f'sim_{ns[1:]}', ['sim_node.sim_node', '--ros-args', *ros_args, *sim_args, *remap],
            env, log_dir)
        procs[f'controller{ns}'] = start_node(
            f'controller_{ns[1:]}', [f'{PKG}.ros.controller.controller_node', '--ros-args',
                                     *ros_args, *remap], env, log_dir)
    # the yardstick takes the first arm's inputs, as its controller does
    procs['bare'] = start_node('bare', [f'{PKG}.ros.lab.bare_node', '--ros-args', '-r',
                                        f'__ns:={namespaces[0]}'], env, log_dir)
    return namespaces


def _warm_up(watch: _Watcher, namespaces: Sequence[str], procs: dict) -> None:
    deadline = time.monotonic() + WARM_UP_TIMEOUT_S
    while not all(watch.get(f'{ns}/hybrid_force_controller')[1].get('mode') == 'running'
                  for ns in namespaces):
        dead = [n for n, p in procs.items() if p.poll() is not None]
        if dead or time.monotonic() > deadline:
            raise RuntimeError(f'the arms did not start running (exited: {dead})')
        time.sleep(0.1)


def _arm_figures(ns: str, watch: _Watcher, sims: tuple, window: tuple, cpu: dict) -> dict:
    """One arm's figures: commands per second of the sim's own time between two reports."""
    (s0, s1), (t0, t1) = sims, window
    tracking = watch.tracking[ns].figures(t0, t1)
    sim_s = float(s1['sim_time_s']) - float(s0['sim_time_s'])
    return {'commands_per_s_at_plant': round((int(s1['commands']) - int(s0['commands']))
                                             / sim_s, 1),
            'sim_command_timeouts': int(s1.get('command_timeouts', 0))
            - int(s0.get('command_timeouts', 0)),
            'controller_cpu_percent': round(cpu[f'controller{ns}'], 1),
            'sim_cpu_percent': round(cpu[f'sim{ns}'], 1),
            'controller_cpu_over_bare': round(cpu[f'controller{ns}'] / cpu['bare'], 2),
            **{f'tracking_{k}': v for k, v in tracking.items()}}


def multi_arm_figures(arms: int, duration_s: float, ros_args: Sequence[str],
                      sim_args: Sequence[str], n_W: Sequence[float], f_d: float,
                      domain: int | None = None) -> dict[str, Any]:
    """Run ``arms`` pairs for ``duration_s`` s of measurement; the figures per arm (docstring)."""
    domain = int(os.environ.get('ROS_DOMAIN_ID', '38')) if domain is None else domain
    env = cell_env(dict(os.environ, ROS_DOMAIN_ID=str(domain)))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    procs: dict = {}
    with tempfile.TemporaryDirectory(prefix='bench_arms_') as tmp:
        namespaces = [f'/arm{k + 1}' for k in range(arms)]
        watch = _Watcher(domain, namespaces, np.asarray(n_W, dtype=float), f_d)
        try:
            _launch(arms, ros_args, sim_args, env, Path(tmp), procs)
            _warm_up(watch, namespaces, procs)
            sims0 = {ns: watch.wait_new(f'{ns}/sim') for ns in namespaces}
            meter = CpuMeter({n: p.pid for n, p in procs.items()})
            stamps0 = {ns: watch.tracking[ns].latest for ns in namespaces}
            meter.start()
            time.sleep(duration_s)
            cpu = meter.stop()
            stamps1 = {ns: watch.tracking[ns].latest for ns in namespaces}
            sims1 = {ns: watch.wait_new(f'{ns}/sim') for ns in namespaces}
            out = {ns: _arm_figures(ns, watch, (sims0[ns], sims1[ns]),
                                    (stamps0[ns], stamps1[ns]), cpu) for ns in namespaces}
        finally:
            stop_nodes(procs)
            watch.close()
    return {'ros_arms': arms, 'ros_duration_s': duration_s,
            'bare_cpu_percent': round(cpu['bare'], 1), 'arms': out}
