"""Finding the package's files and starting its nodes as processes (shared by demo and bench)."""
from __future__ import annotations

import os
import signal
import subprocess
from typing import Iterable

from ..common.package_files import find_config, LOOPBACK_PROFILE, PKG, PROFILE_VAR

__all__ = ['LOOPBACK_PROFILE', 'PAPER_MASSES_OFF', 'PKG', 'PROFILE_VAR', 'cell_env', 'find_config',
           'stop_processes', 'use_loopback_dds']

# the sim's link masses for the paper's arm in demo and bench: 50 % off the URDF's [1.3, 0.9],
# as a real arm differs from its model (the controller starts from the URDF's and learns them)
PAPER_MASSES_OFF = '[0.65, 1.35]'
# set beside PROFILE_VAR when use_loopback_dds chose the profile (cell_env then removes both)
_CHOSEN_HERE = 'HFC_LOOPBACK_DDS_CHOSEN'


def use_loopback_dds(environ: dict | None = None) -> str | None:
    """
    Give this process, and the observers it starts, the loopback Fast DDS profile.

    config/fastdds_loopback.xml gives a participant UDPv4 127.0.0.1 locators only, so no other
    process opens a shared-memory port of it. Opening one runs Fast DDS's port health check,
    which can stall the sender 333 ms (docs/results.md, sections 11 and 13): a node that joins
    a running cell (a recorder, a user's script, a test's watcher) stalled the sim or the
    controller that way. Call it before ``rclpy.init``; children inherit the variable, except
    the cell's nodes started with :func:`cell_env`, which keep shared memory between them.

    Parameters
    ----------
    environ : dict, optional
        The environment to set (``os.environ`` by default).

    Returns
    -------
    str or None
        The profile in force: the caller's own when ``FASTRTPS_DEFAULT_PROFILES_FILE`` was
        already set (None if set empty), else the package's.

    """
    environ = os.environ if environ is None else environ
    if PROFILE_VAR in environ:
        return environ[PROFILE_VAR] or None
    environ[PROFILE_VAR] = str(find_config(LOOPBACK_PROFILE))
    environ[_CHOSEN_HERE] = '1'
    return environ[PROFILE_VAR]


def cell_env(environ: dict | None = None) -> dict[str, str]:
    """
    Return the environment of a cell node (the sim, the controller): the caller's DDS settings.

    A copy of ``environ`` (``os.environ`` by default) without the profile that
    :func:`use_loopback_dds` chose: the sim and the controller start together, before any
    contact, and keep shared memory between them (UDP loopback costs the 1 kHz loop: section
    13). A profile the caller set is kept.
    """
    env = dict(os.environ if environ is None else environ)
    if env.pop(_CHOSEN_HERE, None):
        env.pop(PROFILE_VAR, None)
    return env


def stop_processes(procs: Iterable[subprocess.Popen], timeout: float = 30.0) -> None:
    """Stop nodes started as processes, by pid: SIGINT to each, then wait; kill what stays."""
    procs = list(procs)
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()
