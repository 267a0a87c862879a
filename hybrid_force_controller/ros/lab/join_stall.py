"""
``python -m hybrid_force_controller.ros.lab.join_stall``: joining nodes against the cell.

Starts the sim and the controller as ``demo --arm ARM --physics PHYSICS`` does (``NAME:=VALUE``
after ``--sim`` or ``--controller`` are added), lets them run ``--warm-up`` s, then alternates
``--rounds`` times a quiet stretch of ``--joins`` s with a stretch in which one new process
joins every second. A joiner (``--probe all``, the default) starts with Fast DDS's defaults
on the user's domain (``ROS_DOMAIN_ID``, no profile), waits 0.5 s for the graph and
subscribes to every topic it sees, as ``ros2 bag record -a`` does, then spins 1.5 s
(``node``: one subscription to ``~/x``; ``plain``: imports, no node).

The gaps are measured **at the plant**: the sim reports each second the largest gap between
two efforts it received (``/diagnostics`` ``command_gap_max_ms``), which this program reads
on the cell's domain (``HFC_CELL_DOMAIN_ID``; the user's when that is ``off``) with the
gateway's profile (config/fastdds_udp.xml; joined at the start, as the gateway). It prints, as
JSON, the largest gap in each stretch, how many seconds had one over 100 ms (the sim's
command watchdog) and the fewest efforts a second. docs/results.md, sections 11, 13 and 15.
"""
from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import tempfile
import time
from typing import Sequence


__all__ = ['main']

PROBES = {
    'all': ('import rclpy, time\nfrom rclpy.qos import qos_profile_sensor_data as q\n'
            'rclpy.init()\nn = rclpy.create_node("join_probe")\n'
            'def spin(s):\n    t = time.monotonic()\n    while time.monotonic() - t < s:\n'
            '        rclpy.spin_once(n, timeout_sec=0.05)\n'
            'spin(0.5)\nimport importlib\n'
            'for name, types in n.get_topic_names_and_types():\n'
            '    pkg, kind, cls = types[0].split("/")\n'
            '    try:\n'
            '        t = getattr(importlib.import_module(pkg + "." + kind), cls)\n'
            '    except Exception:\n        continue\n'
            '    n.create_subscription(t, name, lambda m: None, 10, raw=True)\n'
            'spin(1.5)\n'),
    'node': ('import rclpy, time\nfrom geometry_msgs.msg import PointStamped\nrclpy.init()\n'
             "n = rclpy.create_node('join_probe')\n"
             "n.create_subscription(PointStamped, 'hybrid_force_controller/x', print, 10)\n"
             't = time.monotonic()\nwhile time.monotonic() - t < 1.5:\n'
             '    rclpy.spin_once(n, timeout_sec=0.05)\n'),
    'plain': 'import numpy, rclpy, pinocchio, time\ntime.sleep(1.5)\n'}
WATCHDOG_S = 0.1


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='join_stall', description=__doc__.splitlines()[1].strip())
    ap.add_argument('--arm', choices=('paper', 'panda'), default='panda')
    ap.add_argument('--physics', choices=('paper', 'mujoco'), default=None,
                    help='default: mujoco for the Panda, paper for the paper arm')
    ap.add_argument('--rounds', type=int, default=2, help='quiet + joining stretches')
    ap.add_argument('--joins', type=int, default=10, help='joins per stretch, one a second')
    ap.add_argument('--probe', choices=tuple(PROBES), default='all')
    ap.add_argument('--warm-up', type=float, default=8.0, help='s before the first stretch')
    ap.add_argument('--sim', nargs='*', default=[], metavar='NAME:=VALUE')
    ap.add_argument('--controller', nargs='*', default=[], metavar='NAME:=VALUE')
    return ap


def _spin_for(executor, seconds: float) -> None:
    t = time.monotonic()
    while time.monotonic() - t < seconds:
        executor.spin_once(timeout_sec=0.02)


def _stretch_gaps(reports: list[tuple], start: float, end: float) -> tuple[float, int, float]:
    """
    Summarise the sim's reports within [start, end].

    Returns the largest command gap (ms), how many reports had one over 100 ms, and the lowest
    commands/s.
    Each report covers the second before it, so those in [start + 1, end] cover the stretch.
    """
    inside = [(gap, rate) for t, gap, rate in reports if start + 1.0 <= t <= end]
    if not inside:
        return math.nan, 0, math.nan
    gaps = [g for g, _ in inside]
    return round(max(gaps), 1), sum(g > WATCHDOG_S * 1e3 for g in gaps), \
        round(min(r for _, r in inside), 1)


def _run_stretch(executor, joining: bool, joins: int, probe: str,
                 env: dict) -> tuple[float, float]:
    """Run one stretch of ``joins`` s; with ``joining`` a probe process starts every second."""
    start, procs = time.monotonic(), []
    try:
        for _ in range(joins):
            if joining:
                procs.append(subprocess.Popen([sys.executable, '-c', PROBES[probe]], env=env,
                                              stdout=subprocess.DEVNULL,
                                              stderr=subprocess.DEVNULL))
            _spin_for(executor, 1.0)
        _spin_for(executor, 2.0)  # the last joiner's subscriptions, and the sim's report
    finally:
        for p in procs:
            p.wait(timeout=30)
    return start, time.monotonic()


def _monitor(domain: int):
    """
    Make this process's node on the cell's domain (UDP profile), collecting the sim's reports.

    A report: (reception time, the largest gap between two efforts that reached the sim in
    the second before, ms; the efforts it took per second).
    """
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor
    from diagnostic_msgs.msg import DiagnosticArray
    context = Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node('join_stall_monitor', context=context)
    reports: list[tuple] = []

    def on_diagnostics(msg: DiagnosticArray) -> None:
        for status in msg.status:
            values = {kv.key: kv.value for kv in status.values}
            if 'command_gap_max_ms' in values and status.name.endswith('simulated arm'):
                reports.append((time.monotonic(), float(values['command_gap_max_ms']),
                                float(values['commands_per_s'])))
    node.create_subscription(DiagnosticArray, '/diagnostics', on_diagnostics, 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    return executor, reports


def main(argv: Sequence[str] | None = None) -> int:
    """Run the stretches; print the gaps as JSON; 0, or 2 when a node ended early."""
    args = _parser().parse_args(argv)
    from ..programs.demo import _scenario_args, _sim_masses, _start_nodes
    from ..programs.launch import cell_env, find_config, PROFILE_VAR, stop_processes
    from ..common.cell import cell_domains
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    physics = args.physics or ('mujoco' if args.arm == 'panda' else 'paper')
    cfg = argparse.Namespace(arm=args.arm, physics=physics, friction=None, tool_mass=None,
                             masses=None)
    ros_args, mu, _ = _scenario_args(cfg)
    extra = {k: [a for p in getattr(args, k) for a in ('-p', p)] for k in ('sim', 'controller')}
    log_dir = Path(tempfile.mkdtemp(prefix='join_stall_'))
    probe_env = {k: v for k, v in os.environ.items() if k != PROFILE_VAR}  # Fast DDS defaults
    procs = _start_nodes(ros_args, mu, False, cell_env(), log_dir,
                         _sim_masses(cfg) + extra['sim'], extra['controller'])
    os.environ[PROFILE_VAR] = str(find_config('fastdds_udp.xml'))  # the monitor: UDP only
    executor, reports = _monitor(cell_domains().node_domain)
    try:
        _spin_for(executor, args.warm_up)
        rounds = []
        for _ in range(args.rounds):
            for joining in (False, True):
                start, end = _run_stretch(executor, joining, args.joins, args.probe, probe_env)
                rounds.append((joining, start, end))
        if any(p.poll() is not None for p in procs) or not reports:
            print(f'join_stall: a node ended or sent nothing; logs in {log_dir}', file=sys.stderr)
            return 2
        out = {'arm': args.arm, 'physics': physics, 'probe': args.probe,
               'cell_domain': os.environ.get('HFC_CELL_DOMAIN_ID', 'auto')}
        for key, joining in (('quiet', False), ('joining', True)):
            gaps = [_stretch_gaps(reports, s, e) for j, s, e in rounds if j == joining]
            out[f'{key}_max_gap_ms'] = [g for g, _, _ in gaps]
            out[f'{key}_seconds_with_gap_over_100ms'] = sum(n for _, n, _ in gaps)
            out[f'{key}_min_commands_per_s'] = min(r for _, _, r in gaps)
        out['joins'] = args.rounds * args.joins
        print(json.dumps(out))
        return 0
    finally:
        stop_processes(procs)
        for node in executor.get_nodes():
            node.destroy_node()
        executor.shutdown()
        executor.context.try_shutdown()


if __name__ == '__main__':
    sys.exit(main())
