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
ros/lab/tracking.py) with the sim's masses ``--masses`` (default 50 % off the URDF's).
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
from typing import Any, Sequence

import numpy as np

from .cell_processes import Diagnostics, start_node, stop_nodes, WARM_UP_TIMEOUT_S
from .load import CpuMeter, ThreadCpuMeter
from .run_faults import freeze, param_storm
from ..common.cell import cell_domains
from ..programs.launch import cell_env, find_config, PAPER_MASSES_OFF, PKG
from ...tools.offline_bench import offline_figures

__all__ = ['main', 'ros_loop_figures']


def _warm_up(diag: Diagnostics, procs: dict[str, subprocess.Popen]) -> None:
    deadline = time.monotonic() + WARM_UP_TIMEOUT_S
    while diag.get(PKG)[1].get('mode') != 'running' or not diag.get('sim')[1]:
        dead = [n for n, p in procs.items() if p.poll() is not None]
        if dead or time.monotonic() > deadline:
            raise RuntimeError(f'the loop did not start (exited: {dead})')
        time.sleep(0.1)
    time.sleep(2.0)  # the first second of running


def _sim_window(reports: list[dict[str, str]]) -> dict[str, float]:
    """Return the worst effort and joint-state gaps at the plant over the sim's reports."""
    def worst(key: str) -> float:
        values = [float(r.get(key, 'nan')) for r in reports]
        return max((v for v in values if v == v), default=float('nan'))
    return {k: worst(k) for k in ('command_gap_p99_ms', 'command_gap_max_ms',
                                  'state_gap_p99_ms', 'state_gap_max_ms')}


def _controller_holds(ctrl: dict[str, str]) -> dict[str, Any]:
    """
    Return the controller's holds: the longest (and where), each kind's max, p99.9 and mean.

    ``controller_callbacks_ms_per_state``: the control thread's time inside its callbacks
    (decode, tick, publish: Python) per joint state received; at 1 kHz, x 100 is its percent
    of a core, against the thread's whole CPU in ``cpu_percent_per_thread``.
    """
    keys = [k for k in ctrl if k.startswith('hold_') or k.startswith('loop_hold_')]
    out: dict[str, Any] = {f'controller_{k}': float(ctrl[k]) for k in keys
                           if not k.endswith(('_count', '_where'))}
    out['controller_loop_hold_max_where'] = ctrl.get('loop_hold_max_where', '')
    # the control thread inside its Python callbacks, per joint state (1 kHz: % of a core)
    kinds = [k[len('hold_'):-len('_count')] for k in ctrl
             if k.startswith('hold_') and k.endswith('_count')]
    n_states = float(ctrl.get('hold_joint_states_count', 0.0))
    busy = sum(float(ctrl[f'hold_{k}_count']) * float(ctrl.get(f'hold_{k}_mean_ms', 0.0))
               for k in kinds if float(ctrl[f'hold_{k}_count']) > 0.0)
    out['controller_callbacks_ms_per_state'] = round(busy / n_states, 4) if n_states else \
        float('nan')
    return out


def _launch(cfg: dict[str, Any], env: dict[str, str], log_dir: Path,
            procs: dict[str, subprocess.Popen]) -> None:
    """Start the processes of a run into ``procs`` (one by one: a signal stops those started)."""
    ros_args = ['--ros-args', *cfg['scenario'], *cfg['params']]
    pin = ['taskset', '-c', '0'] if cfg['one_core'] else []
    procs['sim'] = start_node('sim', ['sim_node.sim_node', *ros_args, *cfg['sim_args']],
                              env, log_dir, pin)
    ctrl = [f'{PKG}.ros.controller.controller_node', *ros_args]
    procs['controller'] = start_node('controller', ctrl, env, log_dir, pin)
    near = dict(env, ROS_DOMAIN_ID=str(cell_domains(env).node_domain))  # the cell's domain
    procs['bare'] = start_node('bare', [f'{PKG}.ros.lab.bare_node'], near, log_dir)
    if cfg['load_duty'] > 0.0:
        bag = log_dir / f'bag_{time.monotonic_ns()}'
        procs['recorder'] = start_node(
            'recorder', [f'{PKG}.ros.programs.recorder_node', str(bag)], near, log_dir)
        procs['load'] = start_node(
            'load', [f'{PKG}.ros.lab.load', '--duty', str(cfg['load_duty'])], env, log_dir)


def _one_run(cfg: dict[str, Any], domain: int, log_dir: Path) -> dict[str, Any]:
    env = cell_env(dict(os.environ, ROS_DOMAIN_ID=str(domain)))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    # the meter (1 kHz contact wrench) and the bare node join the cell's own domain with the
    # cell's transport, with or without a gateway: the figures compare the cell, not the
    # mirror a user's 1 kHz reader would cost on ROS_DOMAIN_ID (docs/results.md, section 16)
    watch = cell_domains(env).node_domain
    diag = Diagnostics(watch, *cfg['n_f_d'])
    procs: dict[str, subprocess.Popen] = {}
    extra: dict[str, Any] = {}
    try:
        _launch(cfg, env, log_dir, procs)
        _warm_up(diag, procs)
        meter = CpuMeter({n: p.pid for n, p in procs.items() if n != 'load'})
        threads = {n: ThreadCpuMeter(procs[n].pid) for n in ('controller', 'sim', 'bare')}
        sim0 = diag.wait_new('sim', time.monotonic())
        t0 = time.monotonic()
        meter.start()
        for m in threads.values():
            m.start()
        t_stamp0 = diag.tracking.latest
        frozen = freeze(procs['controller'], cfg['freezes'], cfg['freeze_ms'] * 1e-3,
                        diag.tracking)
        if cfg['param_storm'] > 0.0:
            time.sleep(2.0)
            extra = param_storm(diag, cfg['param_storm'], 5.0)
        time.sleep(max(cfg['duration'] - (time.monotonic() - t0), 0.0))
        cpu = meter.stop()
        per_thread = {n: m.stop() for n, m in threads.items()}
        t_end = diag.tracking.latest
        sim1 = diag.wait_new('sim', time.monotonic())
        t1 = time.monotonic()
        ctrl = diag.wait_new(PKG, t1)
        figures = _figures(cfg, diag, cpu, sim0, sim1, t1 - t0, ctrl)
        figures['cpu_percent_per_thread'] = per_thread
        figures.update(_switches({n: m.switches for n, m in threads.items()},
                                 figures['commands_per_s_at_plant']))
        figures.update(_tracking(diag, t_stamp0, t_end, frozen, extra))
    finally:
        stop_nodes(procs)
        diag.close()
    return figures


def _switches(switches: dict[str, dict[str, tuple[float, float]]],
              commands_per_s: float) -> dict[str, Any]:
    """
    Each thread's context switches per s, and each process's per command at the plant.

    ``{process}_wakeups_per_command``: the voluntary switches of all its threads (each a sleep
    that a wake-up ends) per command the plant received: how many thread wake-ups one
    period's messages cost the process (issue 33).
    """
    out: dict[str, Any] = {'switches_per_s_per_thread': switches}
    for proc, threads in switches.items():
        total = sum(v for v, _ in threads.values())
        out[f'{proc}_wakeups_per_command'] = round(total / commands_per_s, 2) \
            if commands_per_s > 0.0 else float('nan')
    return out


def _figures(cfg, diag, cpu, sim0, sim1, elapsed, ctrl) -> dict[str, Any]:
    figures = {f'{n}_cpu_percent': round(v, 1) for n, v in cpu.items()}
    for name in ('controller', 'sim'):
        figures[f'{name}_cpu_over_bare'] = round(cpu[name] / cpu['bare'], 2)
    figures['commands_per_s_at_plant'] = round(
        (int(sim1['commands']) - int(sim0['commands'])) / elapsed, 1)
    figures['sim_command_timeouts'] = (int(sim1.get('command_timeouts', 0))
                                       - int(sim0.get('command_timeouts', 0)))
    figures.update(_sim_window(diag.sim_reports(sim0, sim1)))
    for key in ('loop_period_p50_ms', 'loop_period_p99_ms', 'delay_p50_ms', 'delay_p99_ms',
                'delay_max_ms', 'commands_per_s'):
        figures[f'controller_{key}'] = float(ctrl.get(key, 'nan'))
    figures.update(_controller_holds(ctrl))
    figures['sim_lost_periods'] = int(sim1.get('lost_periods', 0))
    physics = [float(r.get('physics_step_mean_us', 'nan')) for r in diag.sim_reports(sim0, sim1)]
    physics = [v for v in physics if math.isfinite(v)]  # the plant's time per step, each report
    figures['sim_physics_step_mean_us'] = round(float(np.mean(physics)), 2) if physics \
        else float('nan')
    return figures


def _tracking(diag, t_stamp0, t_end, frozen, storm) -> dict[str, Any]:
    tracking = diag.tracking.figures(t_stamp0, t_end)
    for k, (t_stop, t_release) in enumerate(frozen):  # each freeze: the 6 s after it
        after = diag.tracking.figures(t_stop, t_release + 6.0)
        tracking[f'freeze{k}_contact_lost_s'] = after['contact_lost_s']
        for key, v in diag.tracking.recovery(t_stop, t_release, 1.0).items():
            tracking[f'freeze{k}_{key}'] = round(v, 4)
    if storm:
        tracking['storm_sets'] = storm['storm_sets']
        tracking['storm_sets_successful'] = storm['storm_sets_successful']
        tracking['storm_settle_s'] = diag.tracking.settle_time(storm['storm_end_wall'], 1.5)
    return {f'tracking_{k}': v for k, v in tracking.items()}


def ros_loop_figures(duration_s: float = 20.0, load_duty: float = 0.3,
                     params: Sequence[str] = (), domain: int | None = None,
                     freezes: int = 0, freeze_ms: float = 30.0, one_core: bool = False,
                     param_storm: float = 0.0, loaded: bool = True,
                     scenario: Sequence[str] | None = None, sim_args: Sequence[str] = (),
                     n_f_d: tuple[Sequence[float], float] = ((0.0, -1.0, 0.0), 1.0)
                     ) -> dict[str, Any]:
    """
    Measure the real-time loop alone and (``loaded``) under load.

    Load: a recorder and ``load_duty`` of a core busy. ``freezes``: SIGSTOP the controller
    for ``freeze_ms`` that many times in each run; ``one_core``: the sim and the controller
    pinned to CPU 0; ``param_storm``: parameter sets per second during 5 s of each run.
    ``scenario``: the ``--ros-args`` of both nodes (default: config/params.yaml), ``sim_args``
    the sim's own, ``n_f_d`` the normal and f_d the tracking figures use.
    """
    scenario = ['--params-file', str(find_config())] if scenario is None else list(scenario)
    domain = int(os.environ.get('ROS_DOMAIN_ID', '38')) if domain is None else domain
    cfg = {'duration': duration_s, 'params': list(params), 'freezes': freezes,
           'freeze_ms': freeze_ms, 'one_core': one_core, 'param_storm': param_storm,
           'scenario': scenario, 'sim_args': list(sim_args), 'n_f_d': n_f_d}
    out: dict[str, Any] = {'ros_duration_s': duration_s, 'ros_params': list(params),
                           'ros_one_core': one_core, 'ros_param_storm_per_s': param_storm}
    with tempfile.TemporaryDirectory(prefix='bench_ros_') as tmp:
        out['ros_alone'] = _one_run({**cfg, 'load_duty': 0.0}, domain, Path(tmp))
        if loaded:
            out[f'ros_with_recorder_and_{round(100 * load_duty)}pct_load'] = _one_run(
                {**cfg, 'load_duty': load_duty}, domain, Path(tmp))
    return out


def _params(args: argparse.Namespace) -> list[str]:
    """Return ``-p`` arguments of both nodes: the sim's masses and ``--param``."""
    masses = args.masses or (PAPER_MASSES_OFF if args.arm == 'paper' else None)
    named = ([f'masses:={masses}'] if masses else []) + list(args.param)
    return [a for p in named for a in ('-p', p)]


def _scenario(args: argparse.Namespace) -> dict[str, Any]:
    """Return the scenario of ``--arm``/``--physics`` (as ``demo`` runs it) for a run."""
    from ..programs.demo import _scenario_args
    ros_args, mu, _ = _scenario_args(args)
    sim_args = ['-p', f'surface_friction:={mu!r}'] if args.physics == 'mujoco' else []
    n_f_d = ((0.0, -1.0, 0.0), 1.0) if args.arm == 'paper' else ((0.0, 0.0, -1.0), 5.0)
    return {'scenario': ros_args, 'sim_args': sim_args, 'n_f_d': n_f_d}


def main(argv: Sequence[str] | None = None) -> int:
    """Print the benchmark figures as one JSON object (0; 2 if the ROS loop failed)."""
    ap = argparse.ArgumentParser(prog='bench', description=__doc__.splitlines()[0])
    ap.add_argument('--ros', action='store_true', help='also run the 1 kHz ROS loop')
    ap.add_argument('--ros-duration', type=float, default=20.0, help='ROS loop run time, s')
    ap.add_argument('--load-duty', type=float, default=0.3,
                    help='busy fraction of one core in the loaded run (0-1)')
    ap.add_argument('--param', action='append', default=[], metavar='NAME:=VALUE',
                    help='extra node parameter for both nodes, e.g. tick_mode:=joint_state')
    ap.add_argument('--masses', default=None,
                    help="the sim's link masses (default for the paper's arm [0.65, 1.35]: 50 %% "
                    'off its 1.3, 0.9 kg; the Panda: config/panda_table.yaml, 30 %% off)')
    ap.add_argument('--arm', choices=('paper', 'panda'), default='paper',
                    help="the paper's 2-link arm or the Panda on a table (as demo --arm)")
    ap.add_argument('--physics', choices=('paper', 'mujoco'), default='paper',
                    help="the sim's physics (as demo --physics)")
    ap.add_argument('--friction', type=float, default=None, help='mujoco: friction mu')
    ap.add_argument('--tool-mass', type=float, default=None, help='mujoco: tool mass, kg')
    ap.add_argument('--freezes', type=int, default=0,
                    help='SIGSTOP the controller this many times (2 s apart; 7 s apart, once '
                    'theta_hat is learned, when --freeze-ms is 100 or more)')
    ap.add_argument('--freeze-ms', type=float, default=30.0, help='length of each freeze, ms')
    ap.add_argument('--one-core', action='store_true',
                    help='pin the sim and the controller to CPU 0 (a slow PC)')
    ap.add_argument('--param-storm', type=float, default=0.0, metavar='RATE',
                    help='parameter sets per second (alternating f_d and lambda1) for 5 s')
    ap.add_argument('--alone-only', action='store_true', help='skip the loaded run')
    ap.add_argument('--old-tree', metavar='DIR',
                    help='a checkout of commit 34ec57e: its controller step timed in the '
                    'same run, with the ratio of the tick medians')
    ap.add_argument('--no-offline', action='store_true', help='skip the offline figures')
    ap.add_argument('--arms', type=int, default=0, metavar='N',
                    help='with --ros: N sim + controller pairs in /arm1 ... /armN instead '
                    "(multi_arm.py), each arm's figures")
    args = ap.parse_args(argv)
    try:
        figures = {} if args.no_offline else offline_figures(args.old_tree)
        if args.ros and args.arms > 0:
            from .multi_arm import multi_arm_figures
            scenario = _scenario(args)
            figures.update(multi_arm_figures(
                args.arms, args.ros_duration, [*scenario['scenario'], *_params(args)],
                scenario['sim_args'], *scenario['n_f_d']))
        elif args.ros:
            figures.update(ros_loop_figures(
                args.ros_duration, args.load_duty, _params(args), freezes=args.freezes,
                freeze_ms=args.freeze_ms, one_core=args.one_core,
                param_storm=args.param_storm, loaded=not args.alone_only,
                **_scenario(args)))
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
