"""
``python -m hybrid_force_controller.ros.lab.physics_bench``: the sim's physics side by side.

It prints JSON. It runs the same closed loop (sim + controller, real time, 1 kHz, the config
files of ``demo``) once per ``--physics`` at the same time, each in its own ROS domain (base
``ROS_DOMAIN_ID``, +1, ...), so every physics sees the same machine load. Over the same
``--duration`` s window (after ``--settle`` s) it reports per loop the CPU use of the sim and the
controller (% of one core, ``/proc/<pid>/stat``) and the tracking (ros/lab/tracking.py: RMS
tangential position and true-force errors, contact lost), and the contact lost over the whole run
after the first touch.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time
from typing import Any, Sequence

from .load import CpuMeter
from ..programs.demo import _scenario_args
from ..programs.launch import cell_env, PKG

__all__ = ['main']


def _loop(physics: str, arm: str, friction: float | None, domain: int,
          log_dir: Path) -> dict[str, subprocess.Popen]:
    ns = argparse.Namespace(arm=arm, physics=physics, friction=friction, tool_mass=None)
    ros_args, mu, _ = _scenario_args(ns)
    env = dict(cell_env(), ROS_DOMAIN_ID=str(domain),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    procs = {}
    for name, module, extra in (('sim', 'sim_node.sim_node', ['-p', f'surface_friction:={mu!r}']),
                                ('controller', f'{PKG}.ros.controller.controller_node', [])):
        with open(log_dir / f'{physics}_{name}.log', 'wb') as log:
            procs[name] = subprocess.Popen(
                [sys.executable, '-m', module, '--ros-args', *ros_args, *extra], env=env,
                stdout=log, stderr=subprocess.STDOUT)
    return procs


class _Meter:
    """A TrackingMeter spun in its own context in ``domain``."""

    def __init__(self, domain: int, n_W: list[float], f_d: float) -> None:
        import rclpy
        import numpy as np
        from rclpy.signals import SignalHandlerOptions
        from ..common.runner import make_executor
        from .tracking import TrackingMeter
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = rclpy.create_node('physics_bench', context=self.context)
        self.meter = TrackingMeter(self.node, np.array(n_W), f_d)
        self.executor = make_executor('single_threaded', self.context)
        self.executor.add_node(self.node)

    def first_touch(self) -> float:
        """Return the stamp of the first force sample in contact, s (inf: none)."""
        from ...core.runtime.contact import in_contact
        with self.meter.lock:
            return next((t for t, f in self.meter.f if in_contact(f)), float('inf'))

    def close(self) -> None:
        import rclpy
        self.executor.shutdown(timeout_sec=5.0)
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def _spin_all(meters: list[_Meter], seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for m in meters:
            m.executor.spin_once(timeout_sec=0.002)


def run(physics: Sequence[str], arm: str, friction: float | None, duration: float,
        settle: float, base_domain: int) -> dict[str, Any]:
    """Run the loops side by side and return ``{physics: figures}``."""
    n_W, f_d = ([0.0, -1.0, 0.0], 1.0) if arm == 'paper' else ([0.0, 0.0, -1.0], 5.0)
    out: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        loops = {p: _loop(p, arm, friction, base_domain + i, Path(tmp))
                 for i, p in enumerate(physics)}
        meters = {p: _Meter(base_domain + i, n_W, f_d) for i, p in enumerate(physics)}
        try:
            _spin_all(list(meters.values()), settle)
            t0 = {p: m.meter.latest for p, m in meters.items()}
            cpu = CpuMeter({f'{p}_{n}': proc.pid for p, procs in loops.items()
                            for n, proc in procs.items()})
            cpu.start()
            _spin_all(list(meters.values()), duration)
            load = cpu.stop()
            for p, m in meters.items():
                window = m.meter.figures(t0[p], m.meter.latest)
                whole = m.meter.figures(m.first_touch(), m.meter.latest)
                out[p] = {'cpu_sim_percent': load[f'{p}_sim'],
                          'cpu_controller_percent': load[f'{p}_controller'],
                          **window, 'contact_lost_whole_run_s': whole['contact_lost_s']}
        finally:
            for m in meters.values():
                m.close()
            for procs in loops.values():
                for proc in procs.values():
                    proc.terminate()
                for proc in procs.values():
                    proc.wait(30)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the figures as JSON; 0 on success."""
    ap = argparse.ArgumentParser(prog='physics_bench', description=__doc__.splitlines()[1])
    ap.add_argument('--physics', nargs='+', default=['paper', 'mujoco'])
    ap.add_argument('--arm', choices=('paper', 'panda'), default='paper')
    ap.add_argument('--friction', type=float, default=None)
    ap.add_argument('--duration', type=float, default=20.0, help='measured window, s')
    ap.add_argument('--settle', type=float, default=5.0, help='before the window, s')
    args = ap.parse_args(argv)
    base = int(os.environ.get('ROS_DOMAIN_ID', '39'))
    figures = run(args.physics, args.arm, args.friction, args.duration, args.settle, base)
    print(json.dumps({'arm': args.arm, 'friction': args.friction, **figures}, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
