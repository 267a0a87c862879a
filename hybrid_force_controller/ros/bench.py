"""``bench`` executable: speed figures as JSON; ``--ros`` adds the 1 kHz ROS loop in real time.

Reports the controller's own loop timing from its ``/diagnostics`` (timer period p50/p99,
compute p50/p99, achieved rate) and the command inter-arrival times seen by a subscriber.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from typing import Sequence

import numpy as np

from ..tools.offline_bench import offline_figures
from .launch import find_config


def _diag_values(msg) -> dict[str, str]:
    return {kv.key: kv.value for st in msg.status for kv in st.values}


def ros_loop_figures(duration_s: float = 10.0) -> dict[str, float]:
    """Run sim + controller for ``duration_s`` wall seconds and return the timing figures."""
    import rclpy
    import rclpy.executors
    from diagnostic_msgs.msg import DiagnosticArray
    from std_msgs.msg import Float64MultiArray
    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env.setdefault('ROS_DOMAIN_ID', '38')
    common = ['--ros-args', '--params-file', str(find_config())]
    procs = [subprocess.Popen([sys.executable, '-m', mod, *common], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
             for mod in ('sim_node.sim_node', 'hybrid_force_controller.ros.controller_node')]
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=int(env['ROS_DOMAIN_ID']))
    node = rclpy.create_node('ros_bench', context=context)
    executor = rclpy.executors.SingleThreadedExecutor(context=context)
    executor.add_node(node)
    arrivals: list[float] = []
    last_diag: dict[str, str] = {}
    node.create_subscription(Float64MultiArray, '/effort_controller/commands',
                             lambda _m: arrivals.append(time.perf_counter()), 100)
    node.create_subscription(DiagnosticArray, '/diagnostics',
                             lambda m: last_diag.update(_diag_values(m)), 10)
    try:
        t_end = time.monotonic() + duration_s + 3.0
        while time.monotonic() < t_end:
            executor.spin_once(timeout_sec=0.05)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(timeout=20)
    gaps = np.diff(arrivals[len(arrivals) // 5:]) * 1e3 if len(arrivals) > 10 else np.array([np.nan])
    pick = {k: float(last_diag.get(f'loop_{k}', 'nan'))
            for k in ('rate_hz', 'period_p50_ms', 'period_p99_ms', 'compute_p50_ms',
                      'compute_p99_ms')}
    return {**{f'ros_loop_{k}': round(v, 4) for k, v in pick.items()},
            'ros_commands_received_hz': round(1e3 / float(np.mean(gaps)), 1),
            'ros_command_gap_p99_ms': round(float(np.percentile(gaps, 99)), 4)}


def main(argv: Sequence[str] | None = None) -> int:
    """Print the benchmark figures as one JSON object."""
    ap = argparse.ArgumentParser(prog='bench', description=__doc__.splitlines()[0])
    ap.add_argument('--ros', action='store_true', help='also run the 1 kHz ROS loop')
    ap.add_argument('--ros-duration', type=float, default=10.0, help='ROS loop run time, s')
    args = ap.parse_args(argv)
    figures = offline_figures()
    if args.ros:
        figures.update(ros_loop_figures(args.ros_duration))
    print(json.dumps(figures, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
