"""
``python -m hybrid_force_controller.ros.programs.join_stall``: a node joining stalls the cell.

Starts the sim and the controller as ``demo --arm panda --physics mujoco`` does (``NAME:=VALUE``
after ``--sim`` or ``--controller`` are added), lets them run ``--warm-up`` s, then every 4 s
starts a new process that makes one node with one subscription (``--probe node``; ``--probe
plain``: a process that imports numpy, rclpy and pinocchio and makes no node) and spins it
1.5 s. It
prints, as JSON, the longest gap between two effort messages (``/effort_controller/commands``,
received by this process) in the 4 s after each start, and over the warm-up's last part.
docs/results.md, section 11: gaps of 0.1-0.37 s after 20-50 % of the starts of a node.
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
from typing import Sequence

import numpy as np

__all__ = ['main']

PROBES = {
    'node': ('import rclpy, time\nfrom geometry_msgs.msg import PointStamped\nrclpy.init()\n'
             "n = rclpy.create_node('join_probe')\n"
             "n.create_subscription(PointStamped, 'hybrid_force_controller/x', print, 10)\n"
             't = time.monotonic()\nwhile time.monotonic() - t < 1.5:\n'
             '    rclpy.spin_once(n, timeout_sec=0.05)\n'),
    'plain': 'import numpy, rclpy, pinocchio, time\ntime.sleep(1.5)\n'}
WINDOW_S = 4.0


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='join_stall', description=__doc__.splitlines()[1].strip())
    ap.add_argument('--starts', type=int, default=6, help='processes started, one every 4 s')
    ap.add_argument('--probe', choices=tuple(PROBES), default='node')
    ap.add_argument('--warm-up', type=float, default=12.0, help='s before the first start')
    ap.add_argument('--sim', nargs='*', default=[], metavar='NAME:=VALUE')
    ap.add_argument('--controller', nargs='*', default=[], metavar='NAME:=VALUE')
    ap.add_argument('--loopback-probes', action='store_true',
                    help='start the probes with config/fastdds_loopback.xml (the cell and '
                    "this monitor keep the caller's DDS settings)")
    return ap


def _spin_for(node, seconds: float) -> None:
    import rclpy
    t = time.monotonic()
    while time.monotonic() - t < seconds:
        rclpy.spin_once(node, timeout_sec=0.05)


def _gaps(stamps: list[float], starts: list[float], warm_up_end: float) -> dict:
    t = np.array(stamps)
    gap, after = np.diff(t), t[1:]
    out = {'commands_per_s': round(len(t) / (t[-1] - t[0]), 1),
           'before_ms': round(float(gap[(after > warm_up_end - 6.0) & (after < warm_up_end)]
                                    .max(initial=0.0)) * 1e3, 1)}
    out['after_each_start_ms'] = [round(float(gap[(after > s) & (after < s + WINDOW_S)]
                                              .max(initial=0.0)) * 1e3, 1) for s in starts]
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Run the probe starts; print the gaps as JSON; 0, or 2 when a node ended early."""
    args = _parser().parse_args(argv)
    import rclpy
    from std_msgs.msg import Float64MultiArray
    from .demo import _scenario_args, _start_nodes
    from .launch import cell_env, find_config, LOOPBACK_PROFILE, PROFILE_VAR, stop_processes
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    cfg = argparse.Namespace(arm='panda', physics='mujoco', friction=None, tool_mass=None)
    ros_args, mu, _ = _scenario_args(cfg)
    extra = {k: [a for p in getattr(args, k) for a in ('-p', p)] for k in ('sim', 'controller')}
    log_dir = Path(tempfile.mkdtemp(prefix='join_stall_'))
    probe_env = dict(os.environ)
    if args.loopback_probes:
        probe_env[PROFILE_VAR] = str(find_config(LOOPBACK_PROFILE))
    procs = _start_nodes(ros_args, mu, False, cell_env(), log_dir, extra['sim'],
                         extra['controller'])
    rclpy.init()
    node = rclpy.create_node('join_stall_monitor')
    stamps: list[float] = []
    node.create_subscription(Float64MultiArray, '/effort_controller/commands',
                             lambda _: stamps.append(time.monotonic()), 10)
    try:
        _spin_for(node, args.warm_up)
        warm_up_end, starts = time.monotonic(), []
        for _ in range(args.starts):
            starts.append(time.monotonic())
            probe = subprocess.Popen([sys.executable, '-c', PROBES[args.probe]],
                                     env=probe_env, stdout=subprocess.DEVNULL)
            _spin_for(node, WINDOW_S)
            probe.wait(timeout=30)
        if any(p.poll() is not None for p in procs) or len(stamps) < 2:
            print(f'join_stall: a node ended or sent nothing; logs in {log_dir}', file=sys.stderr)
            return 2
        print(json.dumps({'probe': args.probe, 'loopback_probes': args.loopback_probes,
                          **_gaps(stamps, starts, warm_up_end)}))
        return 0
    finally:
        stop_processes(procs)
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
