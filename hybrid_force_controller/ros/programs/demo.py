"""
``demo`` executable: sim + controller over DDS, recorded to an MCAP bag, then the report.

``demo [--duration S] [--out DIR]`` starts the ``sim`` and ``controller`` nodes as separate
processes (DDS kept on this machine: ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` unless
set), records every relevant topic with a rosbag2 recorder into ``DIR/bag`` (MCAP), and
runs the report on the bag (``DIR/report``: Figs. 3-5 and metrics.json).

By default both nodes run in real time against the wall clock at 1 kHz, as on a robot;
``--lockstep`` makes the sim own the time (it publishes ``/clock``, the controller uses sim
time and the recorder sim time), so the run is the same on a loaded machine. The report's
``metrics.json`` records ``"mode": "real_time"`` or ``"lockstep"``.

``--physics mujoco`` runs the sim on MuJoCo (config/mujoco.yaml: a sphere tool and a wrist
force/torque sensor; ``--friction MU`` on the surface, ``--tool-mass KG`` the tool's mass, which
the sensor feels and the controller's ``tool_mass`` subtracts); ``--arm panda`` runs the bundled
Panda pressing 5 N on a table along a 10 cm line, its sim masses +/-30 % off
(config/panda_params.yaml + config/panda_table.yaml; on MuJoCo friction 0.3 and a 0.1 kg tool
by default). metrics.json also records ``arm``, ``physics``, ``friction`` and ``tool_mass``.

``--task wipe`` (wipe.py) is a user's job instead of the sine: the sim's force sensor is
biased, the controller is configured and its sensor tared (``--no-tare``: not), then activated,
and a separate script (send_path.py) wipes a ``--side`` square on ``~/path`` and waits for it
to be done; the recording ends 1 s later. The metrics then start when the path starts:
``rms_path_error_m`` and ``max_path_error_m`` (the tool's distance from the desired point in the
tangent plane), ``rms_force_error_n`` (the true force along n), ``contact_lost_s``; metrics.json
also records ``task`` and ``tared``. ``demo --arm panda --physics mujoco --task wipe`` is the
issue's wiping demo: 5 N, 5 cm/s, mu 0.3, masses 30 % off.

``--surface plane|tilted|tilted_y|cylinder|sphere`` (with ``--task wipe --arm panda``) puts a
workpiece the controller only roughly knows under the tool (surfaces.py): a plane tilted
0.3 rad about x or y, a cylinder R 0.3 m across the path, a sphere R 0.5 m. The controller is
told n = [0, 0, -1] in every case and learns n_hat (``n_estimation``); the script sends its
square in the told plane, centred on the tool. metrics.json then has ``normal_error_deg`` and
``surface``, and the report draws n_hat against the sim's ``sim/contact_normal`` (fig8).

``--tool disc --tool-radius R`` presses a flat pad; the Panda then seats it on the measured tilt
moments (``--orientation moment``, the default with a disc; ``normal``: its axis held along n_hat,
tilted by ``--tool-tilt`` toward the direction of travel; ``free``: the paper's, the tool turns
as the arm pleases). metrics.json then has
``rms_tool_tilt_error_deg``, ``max_tool_tilt_error_deg`` (the tool axis against the true normal,
less the set tilt) and ``rms_moment_n_m`` (the true tilt moments), and records ``tool``,
``orientation`` and a non-zero ``tool_tilt``.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import shutil
import subprocess
import sys
import time
from typing import Any, Sequence

from .launch import cell_env, find_config, PAPER_MASSES_OFF, PKG, stop_processes, use_loopback_dds
from .surfaces import surface_settings, SURFACES, SurfaceSettings, TOLD_N
from ...core.config.groups import ORIENTATION_MODES

#: physics:=mujoco: the tool's mass, kg (sim and controller, -p tool_mass): a 0.1 kg tool on the
#: Panda's wrist sensor, which the controller compensates; the paper's arm keeps a massless tip
TOOL_MASS = {'paper': 0.0, 'panda': 0.1}
TILT_N_TIME_CONSTANT = 1.0  # s: n_hat's time constant under a tilted pad (_orientation_args)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='demo', description=__doc__.splitlines()[0])
    ap.add_argument('--duration', type=float, default=20.0, help='recorded time, s (>= 6)')
    ap.add_argument('--out', type=Path, default=Path('out/demo'), help='output directory')
    ap.add_argument('--lockstep', action='store_true',
                    help='deterministic: the sim owns the time (/clock), one step per command')
    ap.add_argument('--timeout', type=float, default=900.0, help='wall-time limit, s')
    ap.add_argument('--arm', choices=('paper', 'panda'), default='paper',
                    help="the paper's 2-link arm (default) or the Panda on a table")
    ap.add_argument('--physics', choices=('paper', 'mujoco'), default='paper',
                    help="the sim's physics (mujoco: MuJoCo, sphere tool, wrist sensor)")
    ap.add_argument('--friction', type=float, default=None,
                    help='mujoco: friction mu of the surface (default 0; the Panda 0.3)')
    ap.add_argument('--masses', default=None,
                    help="the sim's true link masses, as the arm differs from its URDF (default: "
                    f'the paper arm {PAPER_MASSES_OFF}, 50 %% off; the Panda: 30 %% off, '
                    'config/panda_table.yaml); the controller starts from the URDF and learns '
                    'them (Fig. 5)')
    ap.add_argument('--task', choices=('sine', 'wipe'), default='sine',
                    help="sine: the paper's reference (default); wipe: tare the biased sensor, "
                    'then wipe a --side square from a separate script (wipe.py)')
    ap.add_argument('--side', type=float, default=0.1, help='wipe: side of the square, m')
    ap.add_argument('--surface', choices=SURFACES, default=None,
                    help='wipe, the Panda: the workpiece (surfaces.py), the controller told '
                    'n = [0, 0, -1] with n_estimation, the square centred on the tool in the '
                    'told plane (default: the table, n told right, no estimation)')
    ap.add_argument('--sim-param', action='append', default=[], metavar='NAME:=VALUE',
                    help="a parameter of the sim's, after the others (repeat): e.g. "
                    "'surface_normal:=[-0.2955, -0.9553, 0.0]'")
    ap.add_argument('--controller-param', action='append', default=[], metavar='NAME:=VALUE',
                    help="a parameter of the controller's, after the others (repeat): e.g. "
                    'n_estimation:=true')
    ap.add_argument('--no-tare', action='store_true',
                    help='wipe: skip the tare (the sensor bias stays in the force)')
    ap.add_argument('--tool-mass', type=float, default=None,
                    help="mujoco: mass of the tool, kg, in the sim and the controller's "
                    'tool_mass (default 0; the Panda 0.1)')
    ap.add_argument('--tool', choices=('sphere', 'disc'), default=None,
                    help="mujoco: the sim's tool_shape (default sphere): disc, a flat pad")
    ap.add_argument('--tool-radius', type=float, default=None,
                    help="mujoco: the sim's tool_radius, m (default 0.01)")
    ap.add_argument('--orientation', choices=ORIENTATION_MODES, default=None,
                    help="the Panda: the controller's orientation_mode (default moment with "
                    '--tool disc, else free)')
    ap.add_argument('--tool-tilt', type=float, default=0.0,
                    help="the controller's tool_tilt, rad (with --orientation normal)")
    return ap


def _orientation(args: argparse.Namespace) -> str:
    """Return the orientation_mode of --orientation (default: moment for a disc pad)."""
    if args.orientation is not None:
        return args.orientation
    return 'moment' if args.tool == 'disc' and args.arm == 'panda' else 'free'


def _orientation_args(args: argparse.Namespace) -> list[str]:
    """
    Return the controller's ``-p orientation_mode/tool_tilt`` (none for the paper's free).

    A tilt also sets ``n_time_constant`` to :data:`TILT_N_TIME_CONSTANT` (a
    ``--controller-param`` comes after it and wins): the tilted pad rides its rim, each
    jitter of n_hat moves the rim into the part by ``tool_radius`` times its angle, and
    0.1 s lets the jitter through (docs/results.md section 32).
    """
    mode = _orientation(args)
    out = ['-p', f'orientation_mode:={mode}'] if mode != 'free' else []
    if not args.tool_tilt:
        return out
    return out + ['-p', f'tool_tilt:={float(args.tool_tilt)!r}',
                  '-p', f'n_time_constant:={TILT_N_TIME_CONSTANT!r}']


def _scenario_args(args: argparse.Namespace) -> tuple[list[str], float, float]:
    """``--ros-args`` of both nodes for --arm/--physics/--friction/--tool-mass, mu, the mass."""
    files = ['params.yaml'] if args.arm == 'paper' else ['panda_params.yaml', 'panda_table.yaml']
    mu, mass, tool = 0.0, 0.0, []
    if args.physics == 'mujoco':
        files.append('mujoco.yaml')
        mu = args.friction if args.friction is not None else 0.3 if args.arm == 'panda' else 0.0
        mass = TOOL_MASS[args.arm] if args.tool_mass is None else args.tool_mass
        tool = ['-p', f'tool_mass:={float(mass)!r}']  # the same name in both nodes
    out = [a for name in files for a in ('--params-file', str(find_config(name)))] + tool
    if args.arm == 'panda':
        from ...core.offline.arm7 import panda_urdf_path
        out += ['-p', f'robot_description:={panda_urdf_path()}']
    return out, mu, mass


def _tool_args(args: argparse.Namespace) -> list[str]:
    """Return the sim's ``-p tool_shape/tool_radius`` of --tool and --tool-radius."""
    out = ['-p', f'tool_shape:={args.tool}'] if args.tool else []
    return out + (['-p', f'tool_radius:={float(args.tool_radius)!r}']
                  if args.tool_radius is not None else [])


def _sim_masses(args: argparse.Namespace) -> list[str]:
    """Return the sim's ``-p masses:=...`` (the paper arm's default; the Panda's file's)."""
    masses = args.masses or (PAPER_MASSES_OFF if args.arm == 'paper' else None)
    return ['-p', f'masses:={masses}'] if masses else []


def _start_nodes(ros_args: list[str], mu: float, lockstep: bool, env: dict[str, str],
                 log_dir: Path, sim_args: Sequence[str] = (),
                 ctrl_args: Sequence[str] = ()) -> list[subprocess.Popen]:
    """Start sim and controller as processes; their logs go to LOG_DIR/{sim,controller}.log."""
    common = ['--ros-args', *ros_args]
    sim = [sys.executable, '-m', 'sim_node.sim_node', *common, *sim_args,
           '-p', f'lockstep:={str(lockstep).lower()}', '-p', f'surface_friction:={mu!r}']
    ctrl = [sys.executable, '-m', f'{PKG}.ros.controller.controller_node', *common, *ctrl_args,
            '-p', f'use_sim_time:={str(lockstep).lower()}']
    procs = []
    for name, cmd in (('sim', sim), ('controller', ctrl)):
        with open(log_dir / f'{name}.log', 'wb') as log:
            procs.append(subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT))
    return procs


LOOP_TOPICS = ('/joint_states', '/effort_controller/commands')  # recorded: the time counts


def _record(bag: Path, duration: float, lockstep: bool, procs, timeout: float,
            operator: Any = None) -> None:
    """
    Spin a recorder until its clock has advanced ``duration`` s; show progress.

    The time counts from when the loop's topics (joint states and commands) both reach the
    recorder: under lockstep the sim may run faster than the wall clock, and on one busy core
    the commands' subscription matched 2 s of sim time after the clock's (the bag then held
    8 of its 10 s of commands).

    With ``operator`` (a callable given the recorder's node, returning an object with
    ``poll(elapsed) -> done`` and ``stop()``: wipe.py), until the operator is done instead.
    """
    import rclpy
    from rclpy.parameter import Parameter
    from rclpy.task import Future
    from .recorder_node import BagRecorder, relative
    from ..common.runner import make_executor
    from rclpy.signals import SignalHandlerOptions
    from ..common.cell import cell_domains
    # the recorder and the operator join the cell's own domain (the loopback profile, at the
    # start, before contact), as its integrator would: the bag holds every 1 kHz message the
    # cell sent, which a mirror through the gateway cannot promise under load (README); the
    # user's path script talks to the cell through the gateway
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO,  # Ctrl-C: KeyboardInterrupt
               domain_id=cell_domains().node_domain)
    rec = BagRecorder(bag, start_with=LOOP_TOPICS,
                      parameter_overrides=[Parameter('use_sim_time', value=lockstep)])
    executor = make_executor('events')
    executor.add_node(rec)
    task = None if operator is None else operator(rec)
    loop = [rec.resolve_topic_name(relative(t)) for t in LOOP_TOPICS]
    never = Future()
    try:
        t_wall0, t_start, shown = time.monotonic(), None, -1
        while True:
            executor.spin_until_future_complete(never, timeout_sec=0.05)
            now = rec.get_clock().now().nanoseconds * 1e-9
            if t_start is None and now > 0.0:
                counts = rec.writer.counts  # a copy, under the writer's lock
                t_start = now if all(counts.get(t) for t in loop) else None
            elapsed = 0.0 if t_start is None else now - t_start
            if int(elapsed) != shown:
                shown = int(elapsed)
                total = f'{duration:.0f} s' if task is None else 'the task'
                print(f'\r  recording: {elapsed:5.1f} s of {total}', end='', flush=True)
            if elapsed >= duration if task is None else task.poll(elapsed):
                break
            if any(p.poll() is not None for p in procs):
                raise RuntimeError('a node exited early; see sim.log / controller.log')
            if time.monotonic() - t_wall0 > timeout:
                raise TimeoutError(f'recording did not reach {duration} s in {timeout} s')
        print()
    finally:
        if task is not None:
            task.stop()
        executor.shutdown(timeout_sec=5.0)
        rec.destroy_node()
        rclpy.shutdown()


def _add_mode(metrics_path: Path, mode: str, **setup: object) -> None:
    """Record how the run was timed (and the arm, physics, friction) in metrics.json."""
    metrics = json.loads(metrics_path.read_text())
    metrics['mode'] = mode
    metrics.update(setup)
    metrics_path.write_text(json.dumps(metrics, indent=2) + '\n')


F_D = {'paper': 1.0, 'panda': 5.0}  # N: config/params.yaml, config/panda_table.yaml


def _check(args: argparse.Namespace) -> str:
    """Return what is wrong with the arguments ('' when nothing is)."""
    if args.duration < 6.0:
        return '--duration must be >= 6 s (metrics start at 5 s)'
    for name, value in (('friction', args.friction), ('tool-mass', args.tool_mass),
                        ('tool-radius', args.tool_radius)):
        if value is not None and (args.physics != 'mujoco' or value < 0.0):
            return f'--{name} needs --physics mujoco and a value >= 0'
    if args.tool is not None and args.physics != 'mujoco':
        return "--tool needs --physics mujoco (the paper's physics models a point tool)"
    if (_orientation(args) != 'free' or args.tool_tilt) and args.arm != 'panda':
        return '--orientation and --tool-tilt need --arm panda (a 6-D task: 6 joints or more)'
    if not 0.0 <= args.tool_tilt <= 0.5:
        return '--tool-tilt must be in [0, 0.5] rad'
    if args.task == 'wipe' and not 0.0 < args.side <= 0.5:
        return '--side must be in (0, 0.5] m'
    if args.surface is not None and (args.task != 'wipe' or args.arm != 'panda'):
        return '--surface needs --task wipe and --arm panda'
    for p in args.sim_param + args.controller_param:
        if ':=' not in p or not p.split(':=', 1)[0]:
            return f'a parameter is NAME:=VALUE, got {p!r}'
    return ''


def _operator(args: argparse.Namespace, env: dict[str, str]) -> Any:
    """Return the wipe's operator factory (wipe.py), or None for the sine."""
    if args.task != 'wipe':
        return None
    from .wipe import WipeOperator
    script = [f'{PKG}.ros.programs.send_path', '--side', repr(args.side)]
    if args.surface is not None:  # in the told plane, over the sphere's top
        script += ['--centred', '--normal', *(repr(v) for v in TOLD_N)]
    return lambda node: WipeOperator(node, not args.no_tare, script, env,
                                     args.out / 'script.log', F_D[args.arm])


def _run(args: argparse.Namespace, bag: Path, mode: str) -> tuple[int | None, float, float]:
    """Run the nodes and record; return None (0 when interrupted, 2 on failure), mu, mass."""
    from .wipe import WIPE_CONTROLLER_ARGS, WIPE_SIM_ARGS
    ros_args, mu, tool_mass = _scenario_args(args)
    wipe = args.task == 'wipe'
    shape = (surface_settings(args.surface) if args.surface is not None
             else SurfaceSettings((), ()))
    env = dict(os.environ)
    extra = {who: [a for p in getattr(args, f'{who}_param') for a in ('-p', p)]
             for who in ('sim', 'controller')}
    procs = _start_nodes(ros_args, mu, args.lockstep, cell_env(env), args.out,
                         _sim_masses(args) + (WIPE_SIM_ARGS if wipe else []) + [*shape.sim_args]
                         + _tool_args(args) + extra['sim'],
                         (WIPE_CONTROLLER_ARGS if wipe else []) + [*shape.ctrl_args]
                         + _orientation_args(args) + extra['controller'])
    try:
        _record(bag, args.duration, args.lockstep, procs, args.timeout, _operator(args, env))
    except (RuntimeError, TimeoutError) as exc:
        print(f'\nerror: {exc}', file=sys.stderr)
        return 2, mu, tool_mass
    except KeyboardInterrupt:
        print(f'\ndemo: interrupted; the partial bag is {bag}', file=sys.stderr)
        return 0, mu, tool_mass
    finally:
        stop_processes(procs)
    return None, mu, tool_mass


def _t_start(args: argparse.Namespace, bag: Path) -> float:
    """Return when the metrics start: 5 s, or for the wipe the path's start (bag time)."""
    if args.task != 'wipe':
        return 5.0
    from ...tools.bag_io import load_run
    log = load_run(bag)
    running = log.path_running if log.path_running is not None else log.t < 0.0
    return float(log.t[running.argmax()]) if running.any() else 5.0


def main(argv: Sequence[str] | None = None) -> int:
    """Run the demo; 0 on success, 2 on failure (with the reason on stderr)."""
    args = _parser().parse_args(argv)
    problem = _check(args)
    if problem:
        print(f'error: {problem}', file=sys.stderr)
        return 2
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    os.environ.setdefault('ROS_DOMAIN_ID', '37')
    profile = use_loopback_dds()
    bag, report_dir = args.out / 'bag', args.out / 'report'
    shutil.rmtree(bag, ignore_errors=True)
    args.out.mkdir(parents=True, exist_ok=True)
    mode = 'lockstep' if args.lockstep else 'real_time'
    what = f'{args.duration:.0f} s' if args.task == 'sine' else f'task {args.task}'
    print(f'demo: {args.arm} arm on {args.physics} physics, {what}, '
          f'{mode.replace("_", " ")}, ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]}; '
          f'Fast DDS profile of the recorder and the script: {profile or "the defaults"}')
    code, mu, tool_mass = _run(args, bag, mode)
    if code is not None:  # interrupted (0: the partial bag is kept), or failed (2)
        return code
    from ...tools.report import main as report_main
    print('report:')
    code = report_main([str(bag), '--out', str(report_dir), '--t-start',
                        repr(_t_start(args, bag)), '--tool-tilt', repr(args.tool_tilt)])
    if code == 0:
        _add_mode(report_dir / 'metrics.json', mode, arm=args.arm, physics=args.physics,
                  friction=mu, tool_mass=tool_mass, task=args.task,
                  tared=args.task == 'wipe' and not args.no_tare, surface=args.surface,
                  tool=args.tool or 'sphere', orientation=_orientation(args),
                  **({'tool_tilt': args.tool_tilt} if args.tool_tilt else {}))
        figures = ', '.join(p.name for p in sorted(report_dir.glob('fig*.png')))
        print(f'bag:     {bag}\nfigures: {report_dir}/{figures}\n'
              f'metrics: {report_dir}/metrics.json')
    return code


if __name__ == '__main__':
    sys.exit(main())
