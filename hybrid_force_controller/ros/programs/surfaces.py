"""
Issue 24's workpieces in real time: each surface's settings, and a runner for their figures.

:func:`surface_settings` says, per surface, what the sim is given (``-p`` arguments: its shape
and pose; the Panda on the table of config/panda_table.yaml, its tool touching at the start)
and what the controller is given (told n = [0, 0, -1], the table's, with ``n_estimation``, and
holding its start: the task is the path), and :func:`square_path` the path: an untimed 10 cm
square in the told plane, centred on the tool's start (over the sphere's top; two of its sides
cross the cylinder's axis). ``demo --surface NAME`` runs the same settings.

``python -m hybrid_force_controller.ros.programs.surfaces --surface tilted --runs 3 --out DIR``
runs the Panda on MuJoCo (masses 30 % off, a 0.1 kg tool, friction ``--friction``, default 0.3)
over DDS in real time: sim and controller as processes, a recorder (the bag: ``RECORD_TOPICS``)
and a user node that sends the path once the tool has rested on the surface for ``SETTLE_S``
and waits for ``~/path_status`` ``done``; then ``report`` on the bag. It prints one JSON line
per run: the issue's figures (:func:`issue_figures`) with the report's metrics.json.
``--no-estimation`` and ``--no-friction-removal`` are the negative controls. ``--figures``
draws docs/results.md's figures instead: ``normal_offline.png`` (the Panda told [0, 0, -1] on
the four surfaces offline, paper physics, and the tilted plane without the estimate) and, from
the runs under ``--out``, ``normal_realtime.png`` (the first run of each surface).
"""
from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path
import subprocess
import sys
import time
from typing import Any, NamedTuple, Sequence

import numpy as np

from .launch import cell_env, find_config, PKG, stop_processes, use_loopback_dds

__all__ = ['SURFACES', 'SurfaceSettings', 'issue_figures', 'main', 'run_surface',
           'square_path', 'surface_settings']

TILT_RAD = 0.3
SURFACES = ('plane', 'tilted', 'tilted_y', 'cylinder', 'sphere')
TOLD_N = (0.0, 0.0, -1.0)
PANDA_START = (0.484047, 0.0, 0.41263)  # the tool at PANDA_Q0 (config/panda_table.yaml)
SIDE_M = 0.1
SETTLE_S = 3.0  # the tool rests on the surface this long before the path is sent


class SurfaceSettings(NamedTuple):
    """A surface's ``-p`` arguments for the sim and for the controller."""

    sim_args: tuple[str, ...]
    ctrl_args: tuple[str, ...]


def surface_settings(surface: str, estimation: bool = True,
                     friction_removal: bool = True) -> SurfaceSettings:
    """
    Return the sim's and the controller's arguments for ``surface`` (one of :data:`SURFACES`).

    ``plane`` the table itself; ``tilted`` a plane tilted 0.3 rad about x (across the path's
    first side), ``tilted_y`` about y (along it); ``cylinder`` R = 0.3 m with its axis along y;
    ``sphere`` R = 0.5 m. Each touches the tool at its start with the normal there as stated.
    """
    s, c = math.sin(TILT_RAD), math.cos(TILT_RAD)
    sim = {'plane': [], 'tilted': [f'surface_normal:=[0.0, {s:.6f}, {-c:.6f}]'],
           'tilted_y': [f'surface_normal:=[{s:.6f}, 0.0, {-c:.6f}]'],
           'cylinder': ['surface_shape:=cylinder', 'surface_radius:=0.3',
                        'surface_axis:=[0.0, 1.0, 0.0]'],
           'sphere': ['surface_shape:=sphere', 'surface_radius:=0.5']}
    if surface not in sim:
        raise ValueError(f'surface must be one of {list(SURFACES)}, got {surface!r}')
    ctrl = [f'n:={list(TOLD_N)}', f'n_estimation:={str(estimation).lower()}',
            f'n_friction_removal:={str(friction_removal).lower()}',
            f'ref_center:={list(PANDA_START)}', 'ref_amplitude:=[0.0, 0.0, 0.0]']
    return SurfaceSettings(tuple(a for p in sim[surface] for a in ('-p', p)),
                           tuple(a for p in ctrl for a in ('-p', p)))


def square_path(center: Sequence[float] = PANDA_START, side: float = SIDE_M) -> np.ndarray:
    """Return the corners (5, 3) of the square in the told plane, closed, centred on ``center``."""
    corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]], dtype=float) * side - side / 2
    return np.asarray(center, dtype=float) + np.column_stack([corners, np.zeros(5)])


def _panda_args(friction: float) -> list[str]:
    """Return the Panda on MuJoCo's arguments as ``demo --arm panda --physics mujoco`` has them."""
    from ...core.offline.arm7 import panda_urdf_path
    files = ('panda_params.yaml', 'panda_table.yaml', 'mujoco.yaml')
    return ([a for f in files for a in ('--params-file', str(find_config(f)))]
            + ['-p', 'tool_mass:=0.1', '-p', f'robot_description:={panda_urdf_path()}',
               '-p', f'surface_friction:={friction!r}'])


def _start(settings: SurfaceSettings, friction: float, env: dict[str, str],
           log_dir: Path) -> list[subprocess.Popen]:
    common = ['--ros-args', *_panda_args(friction)]
    cmds = {'sim': [sys.executable, '-m', 'sim_node.sim_node', *common, *settings.sim_args],
            'controller': [sys.executable, '-m', f'{PKG}.ros.controller.controller_node',
                           *common, *settings.ctrl_args]}
    procs = []
    for name, cmd in cmds.items():
        with open(log_dir / f'{name}.log', 'wb') as log:
            procs.append(subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT))
    return procs


class _User:
    """A recorder and a user's node in one context: sends the path, watches its status."""

    def __init__(self, bag: Path) -> None:
        import rclpy
        from rclpy.qos import DurabilityPolicy, QoSProfile
        from rclpy.signals import SignalHandlerOptions
        from nav_msgs.msg import Path as PathMsg
        from std_msgs.msg import String
        from .recorder_node import BagRecorder
        from ..common.runner import make_executor
        self.context = rclpy.Context()
        rclpy.init(context=self.context, signal_handler_options=SignalHandlerOptions.NO)
        self.rec = BagRecorder(bag, context=self.context)
        self.node = rclpy.create_node('surface_user', context=self.context)
        self.pub = self.node.create_publisher(PathMsg, f'{PKG}/path', 10)
        self.status = ''
        latched = QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.node.create_subscription(String, f'{PKG}/path_status', self._on_status, latched)
        self.executor = make_executor('events', self.context)
        for node in (self.rec, self.node):
            self.executor.add_node(node)

    def _on_status(self, msg: Any) -> None:
        self.status = msg.data

    def spin_until(self, predicate, procs, timeout: float, what: str) -> None:
        from rclpy.task import Future
        never, deadline = Future(), time.monotonic() + timeout
        while not predicate():
            self.executor.spin_until_future_complete(never, timeout_sec=0.05)
            if any(p.poll() is not None for p in procs):
                raise RuntimeError(f'a node exited while waiting for {what}')
            if time.monotonic() > deadline:
                raise TimeoutError(f'no {what} in {timeout:g} s')

    def send_path(self, points: np.ndarray) -> None:
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Path as PathMsg
        msg = PathMsg()
        for p in points:
            pose = PoseStamped()
            pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = map(float, p)
            pose.pose.orientation.w = 1.0
            msg.poses.append(pose)
        self.pub.publish(msg)

    def close(self) -> None:
        import rclpy
        self.executor.shutdown(timeout_sec=5.0)
        self.rec.destroy_node()
        self.node.destroy_node()
        rclpy.shutdown(context=self.context)


def run_surface(surface: str, out: Path, friction: float = 0.3, estimation: bool = True,
                friction_removal: bool = True, timeout: float = 180.0) -> dict[str, Any]:
    """
    Run the Panda's square on ``surface`` in real time; return the figures (module docstring).

    ``out`` receives the logs, the bag and the report. Raises RuntimeError or TimeoutError.
    """
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    procs = _start(surface_settings(surface, estimation, friction_removal), friction,
                   cell_env(env), out)
    try:
        user = _User(out / 'bag')
        try:
            user.spin_until(lambda: user.rec.writer.counts.get(f'/{PKG}/x', 0) > 0, procs,
                            90.0, "the controller's telemetry")
            t0 = time.monotonic()
            user.spin_until(lambda: time.monotonic() - t0 > SETTLE_S, procs, 60.0, 'rest')
            user.send_path(square_path())
            user.spin_until(lambda: user.status == 'done', procs, timeout, 'the path done')
            t1 = time.monotonic()
            user.spin_until(lambda: time.monotonic() - t1 > 1.0, procs, 10.0, 'the end')
        finally:
            user.close()
    finally:
        stop_processes(procs)
    from ...tools.report import main as report_main
    if report_main([str(out / 'bag'), '--out', str(out / 'report'), '--t-start', '0']) != 0:
        raise RuntimeError(f'report failed on {out / "bag"}')
    log = (out / 'controller.log').read_text(errors='replace')
    return {'surface': surface, 'friction': friction, 'estimation': estimation,
            'friction_removal': friction_removal, **issue_figures(out / 'bag'),
            'safe_mode_entries': log.count('mode safe:')}


def issue_figures(bag: Path) -> dict[str, Any]:
    """
    Return the issue's figures of a recorded run (tools/normal_analysis.py for the window).

    ``normal_error_deg`` (from 2 s after sliding begins), the true force along the true normal
    (RMS and max over the path's run, N; the RMS also from 2 s after sliding begins), the path
    error (RMS and max, m, in n_hat's tangent plane: at most 1/cos(0.3) = 1.047 times the error
    in the path's own plane) and the time out of contact after the first touch, s.
    """
    from ...tools.analysis import contact_lost_time, normal_force_error
    from ...tools.bag_io import load_run
    from ...tools.normal_analysis import normal_metrics, SETTLE_S as SETTLE_NORMAL_S
    from ...tools.path_analysis import path_metrics, path_window
    log = load_run(bag)
    window, _ = path_window(log, 0.0)
    normal = normal_metrics(log)
    e_f = normal_force_error(log)
    settled = window & (log.t >= normal['sliding_begins_s'] + SETTLE_NORMAL_S)
    return {**normal, **path_metrics(log, 0.0),
            'rms_true_force_error_n': float(np.sqrt(np.mean(e_f[window] ** 2))),
            'max_true_force_error_n': float(np.abs(e_f[window]).max()),
            'rms_true_force_error_settled_n': float(np.sqrt(np.mean(e_f[settled] ** 2)))
            if settled.any() else math.nan,
            'contact_lost_s': contact_lost_time(log), 'path_s': float(np.ptp(log.t[window]))}


_OFFLINE = {'tilted': {'surface_normal': (0.0, math.sin(TILT_RAD), -math.cos(TILT_RAD))},
            'tilted_y': {'surface_normal': (math.sin(TILT_RAD), 0.0, -math.cos(TILT_RAD))},
            'cylinder': {'surface_shape': 'cylinder', 'surface_radius': 0.3,
                         'surface_axis': (0.0, 1.0, 0.0)},
            'sphere': {'surface_shape': 'sphere', 'surface_radius': 0.5}}


def _offline_traces() -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Return (t from the path, normal error deg, true force error N) of the offline runs."""
    from ...core.offline.arm7 import panda_model, panda_scenario, square_path_event
    from ...core.offline.scenario import run_scenario
    model, traces = panda_model(), {}
    runs = [(name, kw, True) for name, kw in _OFFLINE.items()]
    for name, kw, est in runs + [('tilted, estimate off', _OFFLINE['tilted'], False)]:
        sent: dict = {}
        r = run_scenario(panda_scenario(model, 12.0, noise_sigma=0.05, seed=1, **kw,
                                        events=[square_path_event(1.0, SIDE_M, sent)],
                                        overrides={'n': list(TOLD_N), 'n_estimation': est,
                                                   'ref_amplitude': [0.0, 0.0, 0.0]}), model)
        cos = np.clip(np.sum(r.n_hat_W * r.n_true_W, axis=1), -1.0, 1.0)
        traces[name] = (r.t - sent['t'], np.degrees(np.arccos(cos)),
                        np.sum(r.f_true_W * r.n_true_W, axis=1) - 5.0)
    return traces


def _realtime_traces(out: Path) -> dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Return (t from sliding, normal error deg, true force error N) of each surface's run 0."""
    from ...tools.analysis import normal_force_error
    from ...tools.bag_io import load_run
    from ...tools.normal_analysis import normal_error_deg, sliding_begins
    traces = {}
    for name in SURFACES:
        bag = out / f'{name}_0' / 'bag'
        if bag.exists():
            log = load_run(bag)
            traces[name] = (log.t - sliding_begins(log), normal_error_deg(log),
                            normal_force_error(log))
    return traces


def draw(traces: dict, path: Path, title: str, t_label: str) -> Path:
    """Draw the normal error and the true force error of ``traces`` to ``path``."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    fig = Figure(figsize=(7.0, 5.0), dpi=90, layout='constrained')
    FigureCanvasAgg(fig)
    ax_n, ax_f = fig.subplots(2, 1, sharex=True)
    for name, (t, err, f_err) in traces.items():
        style = ':' if 'off' in name else '-'
        ax_n.plot(t, err, style, label=name, lw=1.0)
        ax_f.plot(t, f_err, style, label=name, lw=0.8)
    ax_n.set_ylabel('n_hat to true normal [deg]')
    ax_n.set_ylim(0.0, 20.0)
    ax_n.set_title(title)
    ax_n.legend(loc='upper right', fontsize='small')
    ax_f.set_ylabel('true force - f_d [N]')
    ax_f.set_ylim(-1.0, 1.0)
    ax_f.set_xlabel(t_label)
    for ax in (ax_n, ax_f):
        ax.grid(True, alpha=0.3)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """Run the surfaces (``--runs`` each); one JSON line per run; 0, or 2 on a failed run."""
    ap = argparse.ArgumentParser(prog='surfaces', description=__doc__.splitlines()[0])
    ap.add_argument('--surface', action='append', choices=SURFACES,
                    help='a surface (repeat; default: tilted, tilted_y, cylinder, sphere)')
    ap.add_argument('--runs', type=int, default=1, help='runs of each surface')
    ap.add_argument('--friction', type=float, default=0.3, help="the surface's mu (MuJoCo)")
    ap.add_argument('--no-estimation', action='store_true', help='n_estimation false')
    ap.add_argument('--no-friction-removal', action='store_true',
                    help='n_friction_removal false')
    ap.add_argument('--out', type=Path, default=Path('out/surfaces'), help='output directory')
    ap.add_argument('--figures', type=Path, metavar='DIR',
                    help="draw the figures into DIR (the real-time one from --out's runs)")
    args = ap.parse_args(argv)
    if args.figures is not None:
        print(draw(_offline_traces(), args.figures / 'normal_offline.png',
                   'Offline: the Panda told [0, 0, -1], a 10 cm square at 5 cm/s',
                   't from the path sent [s]'))
        realtime = _realtime_traces(args.out)
        if realtime:
            print(draw(realtime, args.figures / 'normal_realtime.png',
                       'Real time: the Panda on MuJoCo, mu 0.3, told [0, 0, -1]',
                       't from sliding begins [s]'))
        return 0
    os.environ.setdefault('ROS_DOMAIN_ID', '37')
    use_loopback_dds()
    code = 0
    for surface in args.surface or ['tilted', 'tilted_y', 'cylinder', 'sphere']:
        for k in range(args.runs):
            try:
                figures = run_surface(surface, args.out / f'{surface}_{k}', args.friction,
                                      not args.no_estimation, not args.no_friction_removal)
            except (RuntimeError, TimeoutError) as exc:
                print(f'surfaces: {surface} run {k}: {exc}', file=sys.stderr)
                code = 2
                continue
            print(json.dumps({'run': k, **figures}), flush=True)
    return code


if __name__ == '__main__':
    sys.exit(main())
