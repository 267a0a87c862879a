"""Finding the package's files and starting its nodes as processes (shared by demo and bench)."""
from __future__ import annotations

from pathlib import Path
import signal
import subprocess
import sys
from typing import Iterable

__all__ = ['PAPER_MASSES_OFF', 'PKG', 'find_config', 'stop_processes']

PKG = 'hybrid_force_controller'
# the sim's link masses for the paper's arm in demo and bench: 50 % off the URDF's [1.3, 0.9],
# as a real arm differs from its model (the controller starts from the URDF's and learns them)
PAPER_MASSES_OFF = '[0.65, 1.35]'


def find_config(name: str = 'params.yaml') -> Path:
    """config/NAME from the source tree, the pip prefix or the ament index."""
    source_tree = Path(__file__).resolve().parents[3]  # <tree>/<package>/ros/programs/.
    candidates = [source_tree / 'config' / name,
                  Path(sys.prefix) / 'share' / PKG / 'config' / name]
    try:
        from ament_index_python.packages import get_package_share_directory
        candidates.append(Path(get_package_share_directory(PKG)) / 'config' / name)
    except Exception:  # noqa: BLE001 - not in an ament index: other candidates remain
        pass
    for path in candidates:
        if path.is_file():
            return path
    raise FileNotFoundError(f'config/{name} not found in {[str(c) for c in candidates]}')


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
