"""
``python -m hybrid_force_controller.ros.lab.wipe_trials``: the Panda's wipe under faults.

Runs ``demo --arm panda --physics mujoco --task wipe`` (real time) ``--runs`` times, each with
one disturbance while the user's path runs (from when its script has sent the square):

* ``freeze``: the sim and the controller both stopped (SIGSTOP) for ``--freeze-ms`` ms,
  ``--after`` s into the path, then let go (SIGCONT): a hiccup of the whole machine;
* ``joiners``: until the demo ends, a process joins every second (at most two alive at once)
  with Fast DDS's defaults on the user's domain and subscribes to every topic it sees
  (join_stall's probe);
* ``none``: nothing.

It prints one JSON line per run: the demo's exit code and metrics (metrics.json), and from
the bag (tools/cell_trial_figures.py): the fastest joint against its URDF limit, and for a
freeze the time back on the surface and the force RMS outside the 2 s after the release.
docs/results.md, section 16.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import signal
import subprocess
import sys
import tempfile
import time
from typing import Sequence

__all__ = ['main']

PKG = 'hybrid_force_controller'
SENT = 'square from'  # send_path's line once the path is sent
START_TIMEOUT_S = 90.0  # the path is sent within this after the demo starts
END_TIMEOUT_S = 120.0  # the demo ends within this after the path is sent
LIVE_JOINERS = 2  # joiners alive at once, at most (see _joiners)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog='wipe_trials', description=__doc__.splitlines()[1].strip())
    ap.add_argument('--disturb', choices=('freeze', 'joiners', 'none'), default='freeze')
    ap.add_argument('--runs', type=int, default=1)
    ap.add_argument('--freeze-ms', type=float, default=333.0)
    ap.add_argument('--after', type=float, default=4.0, help='s into the path (freeze)')
    ap.add_argument('--surface', default=None, help="demo's --surface (default: its plane)")
    ap.add_argument('--out', type=Path, default=None, help='runs go to OUT/runK (default: tmp)')
    ap.add_argument('--sim-param', action='append', default=[], metavar='NAME:=VALUE',
                    help="the demo's --sim-param (e.g. watchdog_action:=zero)")
    return ap


def _children(pid: int) -> dict[int, str]:
    """Return the live descendants of ``pid`` with their command lines (from /proc)."""
    parents, cmds = {}, {}
    for entry in Path('/proc').iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / 'stat').read_text()
            cmds[int(entry.name)] = (entry / 'cmdline').read_bytes().replace(b'\0', b' ').decode()
        except OSError:
            continue
        parents[int(entry.name)] = int(stat.rsplit(')', 1)[1].split()[1])
    found, frontier = {}, [pid]
    while frontier:
        p = frontier.pop()
        for c, parent in parents.items():
            if parent == p and c not in found:
                found[c] = cmds.get(c, '')
                frontier.append(c)
    return found


def _wait_sent(demo: subprocess.Popen, script_log: Path) -> bool:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline and demo.poll() is None:
        if script_log.exists() and SENT in script_log.read_text(errors='replace'):
            return True
        time.sleep(0.02)  # polling a file another process writes
    return False


def _freeze(demo: subprocess.Popen, hold_s: float) -> tuple[float, float]:
    """SIGSTOP the sim and the controller together for ``hold_s``; wall times of both ends."""
    cell = [p for p, cmd in _children(demo.pid).items()
            if 'sim_node.sim_node' in cmd or 'controller.controller_node' in cmd]
    if len(cell) != 2:
        raise RuntimeError(f'wipe_trials: expected the sim and the controller, found {cell}')
    t_stop = time.time()
    for p in cell:
        os.kill(p, signal.SIGSTOP)
    time.sleep(hold_s)  # the stimulus itself
    for p in cell:
        os.kill(p, signal.SIGCONT)
    return t_stop, time.time()


def _joiners(demo: subprocess.Popen, env: dict[str, str]) -> int:
    """
    Start default-profile joiners until the demo ends, one a second; return how many.

    At most :data:`LIVE_JOINERS` at once: a joiner is a Python process of 1-2 s of CPU, and
    unbounded, on two cores, they pile up until the machine, not DDS, stops the cell (seen:
    100 live joiners, a load of 115).
    """
    from .join_stall import PROBES
    procs, count, deadline = [], 0, time.monotonic() + END_TIMEOUT_S
    try:
        while demo.poll() is None and time.monotonic() < deadline:
            procs = [p for p in procs if p.poll() is None]
            if len(procs) < LIVE_JOINERS:
                procs.append(subprocess.Popen(
                    [sys.executable, '-c', PROBES['all']], env=env,
                    stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
                count += 1
            try:
                demo.wait(timeout=1.0)
            except subprocess.TimeoutExpired:
                pass
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait(timeout=30)
    return count


def _trial(args: argparse.Namespace, out: Path, domain: int) -> dict:
    """Run one demo with its disturbance; return the figures."""
    from ..programs.launch import PROFILE_VAR
    from ...tools.cell_trial_figures import trial_figures
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    cmd = [sys.executable, '-m', f'{PKG}.ros.programs.demo', '--arm', 'panda', '--physics',
           'mujoco', '--task', 'wipe', '--out', str(out)]
    if args.surface:
        cmd += ['--surface', args.surface]
    for p in args.sim_param:
        cmd += ['--sim-param', p]
    out.mkdir(parents=True, exist_ok=True)
    with open(out / 'demo.log', 'wb') as log:
        demo = subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
    stall, joins = None, 0
    try:
        if not _wait_sent(demo, out / 'script.log'):
            raise RuntimeError(f'the path was not sent; see {out}/demo.log')
        if args.disturb == 'freeze':
            time.sleep(args.after)  # into the path
            stall = _freeze(demo, args.freeze_ms * 1e-3)
        elif args.disturb == 'joiners':
            joins = _joiners(demo, {k: v for k, v in env.items() if k != PROFILE_VAR})
        code = demo.wait(timeout=END_TIMEOUT_S)
    finally:
        if demo.poll() is None:
            demo.send_signal(signal.SIGINT)
            demo.wait(timeout=60)
    result = {'demo_exit': code, 'joins': joins}
    metrics = out / 'report' / 'metrics.json'
    if metrics.exists():
        m = json.loads(metrics.read_text())
        keys = ('rms_force_error_n', 'max_force_error_n', 'rms_path_error_m',
                'contact_lost_window_s')
        result.update({f'report_{k}': m.get(k) for k in keys})
    if (out / 'bag').exists():
        result.update(trial_figures(out / 'bag', stall))
    if stall is not None:
        result['stall'] = [round(t, 3) for t in stall]
    return result


def main(argv: Sequence[str] | None = None) -> int:
    """Run the trials; print one JSON line per run; 0 when every demo ended with 0."""
    args = _parser().parse_args(argv)
    root = args.out or Path(tempfile.mkdtemp(prefix='wipe_trials_'))
    domain = int(os.environ.get('ROS_DOMAIN_ID', '61'))
    codes = []
    for k in range(args.runs):
        result = _trial(args, root / f'run{k}', domain)
        result.update(run=k, disturb=args.disturb)
        print(json.dumps(result), flush=True)
        codes.append(result['demo_exit'])
    return 0 if all(c == 0 for c in codes) else 2


if __name__ == '__main__':
    sys.exit(main())
