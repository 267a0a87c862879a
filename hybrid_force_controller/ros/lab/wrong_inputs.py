"""
``python -m hybrid_force_controller.ros.lab.wrong_inputs``: issue 25's figures, as JSON.

Each run starts the sim (masses 50 % off) and the controller in real time with
``config/params.yaml`` as ``bench --ros`` does (its processes, /diagnostics and tracking:
bench.py, tracking.py), waits until theta_hat is learned (tools/recovery_figures.py
``theta_steady``), plays one case, and measures the next ``--window`` s of true force
(``sim/contact_wrench``) and tracking (``~/x``, ``~/x_desired``) with the controller's counters
of refused inputs and its last input fault. Cases (``--case``, repeatable; ``--runs`` each):

* ``wrench_hour``, ``wrench_minute``, ``joint_state_hour``, ``joint_state_minute``: one copy
  of the newest message stamped an hour or a minute ahead (ros/programs/injector.py);
* ``glitch``: one joint state with joint1 0.2 rad off;
* ``fuzz``: 1000 corrupted serialized messages over 2 s on both inputs;
* ``clock_ahead``, ``clock_behind``: the sim's sensor clocks 2 s ahead or behind for the whole
  run (``joint_state_clock_offset``, ``wrench_clock_offset``); nothing is injected.

The controller keeps its default inputs (keep last 1): a single injected message can be
superseded by the sim's next one before the loop reads it; the counters say whether it was.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path
import sys
import tempfile
import time
from typing import Any, Callable, Sequence

import numpy as np

from .cell_processes import Diagnostics, start_node, stop_nodes, WARM_UP_TIMEOUT_S
from .injector import Injector
from ..programs.launch import cell_env, find_config, PKG, use_loopback_dds

__all__ = ['CASES', 'main', 'run_case']

REFUSED = ('joint_state_dropped', 'joint_state_implausible', 'joint_state_clock_implausible',
           'wrench_dropped', 'wrench_implausible', 'wrench_clock_implausible')
Play = Callable[[Injector], None]
CASES: dict[str, tuple[tuple[float, float], Play | None]] = {
    'wrench_hour': ((0.0, 0.0), lambda inj: inj.wrench(3600.0)),
    'wrench_minute': ((0.0, 0.0), lambda inj: inj.wrench(60.0)),
    'joint_state_hour': ((0.0, 0.0), lambda inj: inj.joint_state(3600.0)),
    'joint_state_minute': ((0.0, 0.0), lambda inj: inj.joint_state(60.0)),
    'glitch': ((0.0, 0.0), lambda inj: inj.joint_state(dq=[0.2, 0.0])),
    'fuzz': ((0.0, 0.0), lambda inj: inj.start_fuzz(1000, seed=int(time.time()))),
    'clock_ahead': ((2.0, 2.0), None),
    'clock_behind': ((-2.0, -2.0), None),
}


def _wait(what: str, ok: Callable[[], bool], procs: dict) -> None:
    deadline = time.monotonic() + WARM_UP_TIMEOUT_S
    while not ok():
        dead = [n for n, p in procs.items() if p.poll() is not None]
        if dead or time.monotonic() > deadline:
            raise RuntimeError(f'{what}: not within {WARM_UP_TIMEOUT_S:g} s (exited: {dead})')
        time.sleep(0.1)


def _refused(diag: Diagnostics, before: dict[str, str]) -> bool:
    now = diag.get(PKG)[1]
    return any(int(now.get(k, 0)) > int(before[k]) for k in REFUSED)


def _play(case: str, play: Play | None, injector: Injector, diag: Diagnostics,
          before: dict[str, str]) -> int:
    """
    Play the case; a single message again (up to 5 times) until the controller refused it.

    With keep-last-1 inputs the sim's next message can supersede it before the loop reads
    it (then it never reached the runtime). Returns the number of messages sent.
    """
    if play is None:
        return 0
    for attempt in range(1, 6):
        play(injector)
        if case == 'fuzz':
            return attempt
        deadline = time.monotonic() + 2.5  # /diagnostics comes once a second
        while time.monotonic() < deadline and not _refused(diag, before):
            time.sleep(0.05)
        if _refused(diag, before):
            return attempt
    return 5


def run_case(case: str, domain: int, log_dir: Path, window_s: float = 10.0) -> dict[str, Any]:
    """Run one case once (module docstring) and return its figures."""
    (js_offset, wrench_offset), play = CASES[case]
    env = cell_env(dict(os.environ, ROS_DOMAIN_ID=str(domain)))
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    ros_args = ['--ros-args', '--params-file', str(find_config()), '-p', 'masses:=[0.65, 1.35]']
    diag = Diagnostics(domain)
    injector = Injector(diag.node)
    procs: dict = {}
    try:
        procs['sim'] = start_node('sim', ['sim_node.sim_node', *ros_args,
                                          '-p', f'joint_state_clock_offset:={js_offset}',
                                          '-p', f'wrench_clock_offset:={wrench_offset}'],
                                  env, log_dir)
        procs['controller'] = start_node(
            'controller', [f'{PKG}.ros.controller.controller_node', *ros_args], env, log_dir)
        _wait('the loop to run', lambda: diag.get(PKG)[1].get('mode') == 'running'
              and injector.ready(), procs)
        _wait('theta_hat to be learned', diag.tracking.theta_steady, procs)
        before = diag.wait_new(PKG, time.monotonic())
        t0 = time.time()  # the sim stamps the true force with the wall clock
        attempts = _play(case, play, injector, diag, before)
        time.sleep(max(t0 + window_s - time.time(), 0.0))
        after = diag.wait_new(PKG, time.monotonic())
        out = diag.tracking.figures(t0, t0 + window_s)
        out.update({f'refused_{k}': int(after[k]) - int(before[k]) for k in REFUSED})
        out['last_input_fault'] = after.get('last_input_fault', '')
        out['safe_mode_entries'] = int(after['safe_mode_entries']) - int(
            before['safe_mode_entries'])
        out['controller_alive'] = procs['controller'].poll() is None
        for k in ('joint_state_clock_offset_s', 'wrench_clock_offset_s'):
            out[k] = float(after.get(k, 'nan'))
        out['attempts'] = attempts
        if case == 'fuzz':
            out['fuzz_sent_over_s'] = injector.fuzz_span[1] - injector.fuzz_span[0]
    finally:
        stop_nodes(procs)
        diag.close()
    return out


def _summary(runs: list[dict[str, Any]], injected: bool) -> dict[str, Any]:
    """Worst and median of the figures over the runs (and whether each refused something)."""
    out: dict[str, Any] = {'runs': len(runs)}
    for key in ('rms_force_error_n', 'max_force_n', 'contact_lost_s', 'rms_position_error_m'):
        values = np.array([r[key] for r in runs], dtype=float)
        out[f'{key}_max'] = float(np.nanmax(values))
        out[f'{key}_median'] = float(np.nanmedian(values))
    if injected:
        out['refused_all_runs'] = all(any(r[f'refused_{k}'] for k in REFUSED) for r in runs)
    out['controller_alive_all_runs'] = all(r['controller_alive'] for r in runs)
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """Print the figures of each case (every run and a summary) as one JSON object."""
    ap = argparse.ArgumentParser(prog='wrong_inputs', description=__doc__.splitlines()[1])
    ap.add_argument('--case', action='append', choices=sorted(CASES),
                    help='a case to run (repeatable; default: all)')
    ap.add_argument('--runs', type=int, default=5, help='runs per case')
    ap.add_argument('--window', type=float, default=10.0, help='measured window, s')
    args = ap.parse_args(argv)
    domain = int(os.environ.get('ROS_DOMAIN_ID', '38'))
    use_loopback_dds()
    figures: dict[str, Any] = {}
    try:
        with tempfile.TemporaryDirectory(prefix='wrong_inputs_') as tmp:
            for case in args.case or list(CASES):
                runs = [run_case(case, domain, Path(tmp), args.window) for _ in range(args.runs)]
                figures[case] = {'summary': _summary(runs, CASES[case][1] is not None),
                                 'runs': runs}
                print(json.dumps({case: figures[case]['summary']}), file=sys.stderr)
    except KeyboardInterrupt:
        print('wrong_inputs: interrupted', file=sys.stderr)
    except (RuntimeError, TimeoutError) as exc:
        print(f'wrong_inputs: {exc}', file=sys.stderr)
        return 2
    print(json.dumps(figures, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
