"""
``bench`` executable: speed figures as JSON; ``--ros`` adds the 1 kHz ROS loop in real time.

``bench --ros`` runs the sim and the controller as processes (real time, 1 kHz) for
``--ros-duration`` s (default 20) twice: alone, and under load (a recorder process
subscribed to every topic, plus a process keeping ``--load-duty`` of one core busy). For
each run it reports the CPU use of each process (% of one core: user + system ticks from
``/proc/<pid>/stat`` over the run), the commands per second reaching the plant (counted by
the sim), the controller's tick period p50/p99 and input-to-command delay p50/p99/max
(joint-state stamp to effort published, node clock), read from ``/diagnostics``, and the
tracking over the measured window (RMS position and true-force errors, contact lost:
ros/tracking.py) with the sim's masses ``--masses`` (default 50 % off the URDF's).
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import threading
import time
from typing import Any, Sequence

import numpy as np

from .launch import find_config, PKG
from .load import CpuMeter
from .tracking import TrackingMeter
from ..tools.offline_bench import offline_figures

__all__ = ['main', 'ros_loop_figures']

WARM_UP_TIMEOUT_S = 90.0


class _Diagnostics:
    """Latest /diagnostics values per hardware_id, in a background-spun context."""

    def __init__(self, domain: int) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from .runner import make_executor
        self.latest: dict[str, dict[str, str]] = {}
        self.received: dict[str, float] = {}
        self.lock = threading.Lock()
        self.context = rclpy.Context()
        from rclpy.signals import SignalHandlerOptions
        rclpy.init(context=self.context, domain_id=domain,  # Ctrl-C: KeyboardInterrupt
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('ros_bench', context=self.context)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self._on_diag, 10)
        self.tracking = TrackingMeter(self.node, np.array([0.0, -1.0, 0.0]), 1.0)
        self.executor = make_executor('single_threaded', self.context)
        self.executor.add_node(self.node)
        self.thread = threading.Thread(target=self.executor.spin, daemon=True)
        self.thread.start()

    def _on_diag(self, msg: Any) -> None:
        for st in msg.status:
            with self.lock:
                self.latest[st.hardware_id] = {kv.key: kv.value for kv in st.values}
                self.received[st.hardware_id] = time.monotonic()

    def get(self, hardware_id: str) -> tuple[float, dict[str, str]]:
        with self.lock:
            return self.received.get(hardware_id, 0.0), dict(self.latest.get(hardware_id, {}))

    def wait_new(self, hardware_id: str, after: float, timeout: float = 10.0) -> dict[str, str]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            t, values = self.get(hardware_id)
            if t > after:
                return values
            time.sleep(0.05)
        raise TimeoutError(f'no /diagnostics from {hardware_id} within {timeout} s')

    def close(self) -> None:
        import rclpy
        self.executor.shutdown(timeout_sec=5.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        self.thread.join(5.0)


def _start(name: str, argv: list[str], env: dict[str, str], log_dir: Path) -> subprocess.Popen:
    with open(log_dir / f'{name}.log', 'wb') as log:
        return subprocess.Popen([sys.executable, '-m', *argv], env=env, stdout=log,
                                stderr=subprocess.STDOUT)


def _stop(procs: dict[str, subprocess.Popen]) -> None:
    """SIGINT each process by pid, then SIGKILL what is left."""
    for p in procs.values():
        if p.poll() is None:
            p.send_signal(2)
    for p in procs.values():
        try:
            p.wait(timeout=20)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def _warm_up(diag: _Diagnostics, procs: dict[str, subprocess.Popen]) -> None:
    deadline = time.monotonic() + WARM_UP_TIMEOUT_S
    while diag.get(PKG)[1].get('mode') != 'running' or not diag.get('sim')[1]:
        dead = [n for n, p in procs.items() if p.poll() is not None]
        if dead or time.monotonic() > deadline:
            raise RuntimeError(f'the loop did not start (exited: {dead})')
        time.sleep(0.1)
    time.sleep(2.0)  # the first second of running


def _freeze(proc: subprocess.Popen, count: int, hold_s: float = 0.03) -> list[float]:
    """SIGSTOP the process for ``hold_s`` ``count`` times, 1 s apart; wall times of each."""
    times = []
    for _ in range(count):
        time.sleep(1.0)
        times.append(time.time())
        proc.send_signal(19)  # SIGSTOP: a scheduler hiccup of hold_s
        time.sleep(hold_s)
        proc.send_signal(18)  # SIGCONT
    return times


def _one_run(duration_s: float, load_duty: float, params: list[str], domain: int,
             log_dir: Path, freezes: int = 0) -> dict[str, float]:
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    ros_args = ['--ros-args', '--params-file', str(find_config()), *params]
    procs: dict[str, subprocess.Popen] = {}
    diag = _Diagnostics(domain)
    try:
        procs['sim'] = _start('sim', ['sim_node.sim_node', *ros_args], env, log_dir)
        procs['controller'] = _start('controller', [f'{PKG}.ros.controller_node', *ros_args],
                                     env, log_dir)
        if load_duty > 0.0:
            bag = log_dir / f'bag_{domain}_{time.monotonic_ns()}'
            procs['recorder'] = _start('recorder', [f'{PKG}.ros.recorder_node', str(bag)],
                                       env, log_dir)
            procs['load'] = _start('load', [f'{PKG}.ros.load', '--duty', str(load_duty)],
                                   env, log_dir)
        _warm_up(diag, procs)
        meter = CpuMeter({n: p.pid for n, p in procs.items() if n != 'load'})
        sim0 = diag.wait_new('sim', time.monotonic())
        t0 = time.monotonic()
        meter.start()
        t_stamp0, t_wall0 = diag.tracking.latest, time.monotonic()
        frozen = _freeze(procs['controller'], freezes)
        time.sleep(max(duration_s - (time.monotonic() - t_wall0), 0.0))
        cpu = meter.stop()
        t_end = diag.tracking.latest
        tracking = diag.tracking.figures(t_stamp0, t_end)
        if freezes:  # the window of the freezes, and the last 6 s (after them)
            during = diag.tracking.figures(frozen[0] - 0.5, frozen[-1] + 1.0)
            last = diag.tracking.figures(t_end - 6.0, t_end)
            tracking.update({'freezes': freezes, 'freeze_max_force_n': during['max_force_n'],
                             'freeze_contact_lost_s': during['contact_lost_s'],
                             'last_6s_rms_force_error_n': last['rms_force_error_n']})
        sim1 = diag.wait_new('sim', time.monotonic())
        t1 = time.monotonic()
        ctrl = diag.wait_new(PKG, t1)
    finally:
        _stop(procs)
        diag.close()
    commands = (int(sim1['commands']) - int(sim0['commands'])) / (t1 - t0)
    figures = {f'{n}_cpu_percent': round(v, 1) for n, v in cpu.items()}
    figures['commands_per_s_at_plant'] = round(commands, 1)
    for key in ('loop_period_p50_ms', 'loop_period_p99_ms', 'delay_p50_ms', 'delay_p99_ms',
                'delay_max_ms', 'commands_per_s'):
        figures[f'controller_{key}'] = float(ctrl.get(key, 'nan'))
    figures['sim_lost_periods'] = int(sim1.get('lost_periods', 0))
    figures.update({f'tracking_{k}': v for k, v in tracking.items()})
    return figures


def ros_loop_figures(duration_s: float = 20.0, load_duty: float = 0.3,
                     params: Sequence[str] = (), domain: int | None = None,
                     freezes: int = 0) -> dict[str, Any]:
    """
    Measure the real-time loop alone and under load (recorder + ``load_duty`` of a core).

    ``freezes``: SIGSTOP the controller for 30 ms that many times in each run.
    """
    domain = int(os.environ.get('ROS_DOMAIN_ID', '38')) if domain is None else domain
    with tempfile.TemporaryDirectory(prefix='bench_ros_') as tmp:
        alone = _one_run(duration_s, 0.0, list(params), domain, Path(tmp), freezes)
        loaded = _one_run(duration_s, load_duty, list(params), domain, Path(tmp), freezes)
    return {'ros_duration_s': duration_s, 'ros_params': list(params), 'ros_alone': alone,
            f'ros_with_recorder_and_{round(100 * load_duty)}pct_load': loaded}


def main(argv: Sequence[str] | None = None) -> int:
    """Print the benchmark figures as one JSON object (0; 2 if the ROS loop failed)."""
    ap = argparse.ArgumentParser(prog='bench', description=__doc__.splitlines()[0])
    ap.add_argument('--ros', action='store_true', help='also run the 1 kHz ROS loop')
    ap.add_argument('--ros-duration', type=float, default=20.0, help='ROS loop run time, s')
    ap.add_argument('--load-duty', type=float, default=0.3,
                    help='busy fraction of one core in the loaded run (0-1)')
    ap.add_argument('--param', action='append', default=[], metavar='NAME:=VALUE',
                    help='extra node parameter for both nodes, e.g. tick_mode:=joint_state')
    ap.add_argument('--masses', default='[0.65, 1.35]',
                    help="the sim's link masses (config/params.yaml arm: 1.3, 0.9 kg)")
    ap.add_argument('--freezes', type=int, default=0,
                    help='SIGSTOP the controller for 30 ms this many times (1 s apart)')
    ap.add_argument('--no-offline', action='store_true', help='skip the offline figures')
    args = ap.parse_args(argv)
    try:
        figures = {} if args.no_offline else offline_figures()
        if args.ros:
            params = [a for p in [f'masses:={args.masses}', *args.param] for a in ('-p', p)]
            figures.update(ros_loop_figures(args.ros_duration, args.load_duty, params,
                                            freezes=args.freezes))
    except KeyboardInterrupt:
        print('bench: interrupted', file=sys.stderr)
        return 0
    except (RuntimeError, TimeoutError) as exc:
        print(f'bench: {exc}', file=sys.stderr)
        return 2
    print(json.dumps(figures, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
