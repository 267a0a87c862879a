"""``demo`` executable: sim + controller over DDS, recorded to an MCAP bag, then the report.

``demo [--duration S] [--out DIR]`` starts the ``sim`` and ``controller`` nodes as separate
processes (DDS kept on this machine: ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless
set), records every relevant topic with a rosbag2 recorder into ``DIR/bag`` (MCAP), and
runs the report on the bag (``DIR/report``: Figs. 3-5 and metrics.json).

By default the sim runs in lockstep and publishes ``/clock`` (the controller uses sim
time), so the run is the same on a loaded machine; ``--real-time`` runs both against the
wall clock at 1 kHz instead.
"""
from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from typing import Sequence

from .launch import PKG, find_config


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='demo', description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=20.0, help='recorded time, s (>= 6)')
    ap.add_argument('--out', type=Path, default=Path('out/demo'), help='output directory')
    ap.add_argument('--real-time', action='store_true', help='wall clock instead of lockstep')
    ap.add_argument('--timeout', type=float, default=900.0, help='wall-time limit, s')
    return ap


def _start_nodes(params: Path, lockstep: bool, env: dict[str, str],
                 log_dir: Path) -> list[subprocess.Popen]:
    """sim and controller as processes; their logs go to LOG_DIR/{sim,controller}.log."""
    common = ['--ros-args', '--params-file', str(params)]
    sim = [sys.executable, '-m', 'sim_node.sim_node', *common,
           '-p', f'lockstep:={str(lockstep).lower()}']
    ctrl = [sys.executable, '-m', f'{PKG}.ros.controller_node', *common,
            '-p', f'use_sim_time:={str(lockstep).lower()}']
    procs = []
    for name, cmd in (('sim', sim), ('controller', ctrl)):
        with open(log_dir / f'{name}.log', 'wb') as log:
            procs.append(subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT))
    return procs


def _record(bag: Path, duration: float, lockstep: bool, procs, timeout: float) -> None:
    """Spin a recorder until its clock has advanced ``duration`` s; show progress."""
    import rclpy
    from rclpy.parameter import Parameter
    from .recorder_node import BagRecorder
    rclpy.init()
    rec = BagRecorder(bag, parameter_overrides=[Parameter('use_sim_time', value=lockstep)])
    try:
        t_wall0, t_start, shown = time.monotonic(), None, -1
        while True:
            rclpy.spin_once(rec, timeout_sec=0.05)
            now = rec.get_clock().now().nanoseconds * 1e-9
            if now > 0.0 and t_start is None:
                t_start = now
            elapsed = 0.0 if t_start is None else now - t_start
            if int(elapsed) != shown:
                shown = int(elapsed)
                print(f'\r  recording: {elapsed:5.1f} / {duration:.0f} s', end='', flush=True)
            if elapsed >= duration:
                break
            if any(p.poll() is not None for p in procs):
                raise RuntimeError('a node exited early; see sim.log / controller.log')
            if time.monotonic() - t_wall0 > timeout:
                raise TimeoutError(f'recording did not reach {duration} s in {timeout} s')
        print()
    finally:
        rec.destroy_node()
        rclpy.shutdown()


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; 0 on success, 2 on failure (with the reason on stderr)."""
    args = _parser().parse_args(argv)
    if args.duration < 6.0:
        print('error: --duration must be >= 6 s (metrics start at 5 s)', file=sys.stderr)
        return 2
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', '37')
    bag, report_dir = args.out / 'bag', args.out / 'report'
    shutil.rmtree(bag, ignore_errors=True)
    args.out.mkdir(parents=True, exist_ok=True)
    print(f'demo: {args.duration:.0f} s, {"real time" if args.real_time else "lockstep"}, '
          f'ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]}')
    procs = _start_nodes(find_config(), not args.real_time, dict(os.environ), args.out)
    try:
        _record(bag, args.duration, not args.real_time, procs, args.timeout)
    except (RuntimeError, TimeoutError) as exc:
        print(f'\nerror: {exc}', file=sys.stderr)
        return 2
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            p.wait(timeout=30)
    from ..tools.report import main as report_main
    print('report:')
    code = report_main([str(bag), '--out', str(report_dir)])
    if code == 0:
        print(f'bag:     {bag}\nfigures: {report_dir}/fig3_position.png, fig4_force.png, '
              f'fig5_parameters.png\nmetrics: {report_dir}/metrics.json')
    return code


if __name__ == '__main__':
    sys.exit(main())
