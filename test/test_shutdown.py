"""
Command line and shutdown of every executable.

``--help`` prints usage and exits 0; SIGINT (Ctrl-C) to a running process ends it with
exit code 0 and no traceback.

The executables are started the way their console scripts call them (setup.py's entry
points, checked here). A process is signalled once it is demonstrably running (a log line,
its children, or CPU time spent in its main), never after a bare sleep. ``report`` shares
``paper``'s Ctrl-C wrapper (ros/programs/cli.py); it is not signalled here, as it may end before.
"""
from __future__ import annotations

import os
from pathlib import Path
import re
import signal
import subprocess
import sys

from helpers.ros import domain_id, node_env, NodeProcess, ROOT, wait_for
from hybrid_force_controller.ros.lab.cell_processes import child_pids
from hybrid_force_controller.ros.lab.load import cpu_seconds
import pytest


ENTRY_POINTS = {
    'controller': 'hybrid_force_controller.ros.controller.controller_node:main',
    'sim': 'sim_node.sim_node:main',
    'paper': 'hybrid_force_controller.ros.programs.cli:paper',
    'bench': 'hybrid_force_controller.ros.lab.bench:main',
    'demo': 'hybrid_force_controller.ros.programs.demo:main',
    'report': 'hybrid_force_controller.ros.programs.cli:report',
    'identify_tool': 'hybrid_force_controller.ros.programs.cli:identify_tool',
}
DOMAIN = domain_id('shutdown')


def _command(exe: str, *args: str) -> list[str]:
    """Build what the console script runs: import the entry point, exit with its result."""
    module, func = ENTRY_POINTS[exe].split(':')
    code = f'import sys; from {module} import {func}; sys.exit({func}())'
    return [sys.executable, '-c', code, *args]


def test_entry_points_match_setup_py():
    text = (ROOT / 'setup.py').read_text()
    found = dict(re.findall(r"'(\w+) = ([\w.]+:\w+)'", text))
    assert found == ENTRY_POINTS


@pytest.mark.parametrize('exe', sorted(ENTRY_POINTS))
def test_help_prints_usage_and_exits_0(exe):
    proc = subprocess.run(_command(exe, '--help'), cwd=ROOT, env=node_env(DOMAIN),
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert 'usage:' in proc.stdout and exe in proc.stdout, proc.stdout
    assert 'Traceback' not in proc.stdout + proc.stderr


class _Program(NodeProcess):
    """A program (not a node): its command line exactly as given, no --ros-args."""

    @property
    def command(self) -> list[str]:
        return list(self.command_override)


def _sigint_and_check(proc: NodeProcess, kids: list[int] = ()) -> None:
    """Ctrl-C ends ``proc`` and its ``kids`` cleanly; the kids are killed on every path."""
    try:
        proc.signal(signal.SIGINT)
        wait_for(lambda: not proc.alive,  # a hang says where the program stood (its log)
                 lambda: f'the process to exit after SIGINT; its log:\n{proc.log_since()[-3000:]}'
                 f'\nits children then: {child_pids(proc.pid)}', timeout=30.0)
        log = proc.log_since()
        assert proc.returncode == 0, log[-3000:]
        assert 'Traceback' not in log and 'RCLError' not in log, log[-3000:]
        for kid in kids:
            wait_for(lambda: not _running(kid), f'child {kid} to exit', timeout=30.0)
    finally:
        for kid in kids:
            if _running(kid):  # a failed check leaves no sim or controller running
                os.kill(kid, signal.SIGKILL)


def _running(pid: int) -> bool:
    try:
        return 'Z' not in Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1][:3]
    except OSError:
        return False


@pytest.mark.parametrize('exe, args', [
    ('controller', []),
    ('controller', ['-p', 'executor:=single_threaded']),
    ('controller', ['-p', 'tick_mode:=joint_state']),
    ('sim', []),
    ('sim', ['-p', 'executor:=single_threaded']),  # its spin loop's spin_once on that executor
    ('sim', ['-p', 'lockstep:=true']),
], ids=['controller', 'controller_single_threaded', 'controller_joint_state', 'sim',
        'sim_single_threaded', 'sim_lockstep'])
def test_sigint_ends_a_running_node_cleanly(tmp_path, exe, args):
    """Both nodes run (a closed loop), then the one under test gets SIGINT."""
    other = 'sim' if exe == 'controller' else 'controller'
    lockstep = ['-p', 'use_sim_time:=true'] if args == ['-p', 'lockstep:=true'] else []
    procs = {exe: NodeProcess(exe, tmp_path / f'{exe}.log', DOMAIN, args),
             other: NodeProcess(other, tmp_path / f'{other}.log', DOMAIN, lockstep)}
    for name, p in procs.items():
        p.command_override = _command(name)[:3]
        p.params_file = None
        p.args = ['--params-file', str(ROOT / 'config' / 'params.yaml'), *p.args]
    try:
        for p in procs.values():
            p.start()
        wait_for(lambda: 'mode running' in procs['controller'].log_since(), 'the loop running',
                 alive=list(procs.values()))
        _sigint_and_check(procs[exe])
    finally:
        for p in procs.values():
            p.stop()


def test_sigint_ends_the_recorder_cleanly_and_closes_the_bag(tmp_path):
    rec = NodeProcess('hybrid_force_controller.ros.programs.recorder_node', tmp_path / 'rec.log',
                      DOMAIN,
                      params_file=None, argv=[str(tmp_path / 'bag')])
    with rec:
        wait_for(lambda: 'recording' in rec.log_since(), 'the recorder running', alive=[rec])
        _sigint_and_check(rec)
    assert (tmp_path / 'bag' / 'metadata.yaml').is_file()


@pytest.mark.parametrize('exe, argv, ready', [
    ('demo', ['--duration', '60'], 'recording:'),
    ('bench', ['--ros', '--no-offline', '--ros-duration', '60'], 'children'),
    ('paper', ['--duration', '60'], 'cpu'),
])
def test_sigint_ends_a_running_program_cleanly(tmp_path, exe, argv, ready):
    args = [*argv, '--out', str(tmp_path / 'out')] if exe in ('demo', 'paper') else argv
    proc = _Program(exe, tmp_path / f'{exe}.log', DOMAIN, params_file=None, cwd=tmp_path)
    proc.command_override = _command(exe, *args)
    proc.env = {**node_env(DOMAIN), 'PYTHONPATH': str(ROOT)}
    kids: list[int] = []
    with proc:
        if ready == 'children':
            wait_for(lambda: len(child_pids(proc.pid)) >= 2, 'its node processes', alive=[proc])
            kids = child_pids(proc.pid)
        elif ready == 'cpu':
            wait_for(lambda: not proc.alive or cpu_seconds(proc.pid) > 0.8, 'it running')
            if not proc.alive:
                pytest.fail(f'{exe} ended before the signal: {proc.log_since()[-2000:]}')
        else:
            wait_for(lambda: ready in proc.log_since(), ready, alive=[proc])
            kids = child_pids(proc.pid)
        _sigint_and_check(proc, kids)
