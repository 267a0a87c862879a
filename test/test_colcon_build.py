"""
`colcon build` lays the package out the way `ros2 run` finds it.

ros2run resolves ``ros2 run PKG EXE`` through the ament index: the package marker in
``share/ament_index/resource_index/packages`` gives the prefix, and the executable is
``<prefix>/lib/PKG/EXE``. These tests build into a temporary directory, resolve the
executables exactly that way with ament_index_python, and start them.
"""
import json
import os
from pathlib import Path
import subprocess
import sys

from helpers.ros import domain_id, NodeProcess, Spun, wait_for
import pytest


REPO = Path(__file__).resolve().parents[1]
PKG = 'hybrid_force_controller'
EXECUTABLES = ('controller', 'sim', 'paper', 'bench', 'demo', 'report')
DOMAIN_ID = str(domain_id('colcon_build'))


@pytest.fixture(scope='module')
def install(tmp_path_factory) -> Path:
    """Run colcon build of this repository into a fresh directory; return the install base."""
    base = tmp_path_factory.mktemp('colcon')
    cmd = [sys.executable, '-m', 'colcon', '--log-base', str(base / 'log'), 'build',
           '--base-paths', str(REPO), '--build-base', str(base / 'build'),
           '--install-base', str(base / 'install')]
    proc = subprocess.run(cmd, cwd=base, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    return base / 'install'


def _env(install: Path) -> dict[str, str]:
    """Set what sourcing install/setup.sh would set for this package (isolated layout)."""
    prefix = install / PKG
    site = next((prefix / 'lib').glob('python3*/site-packages'))
    env = dict(os.environ)
    env['AMENT_PREFIX_PATH'] = str(prefix)
    env['PYTHONPATH'] = os.pathsep.join([str(site), env.get('PYTHONPATH', '')])
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_DOMAIN_ID'] = DOMAIN_ID
    return env


def _resolve(install: Path, exe: str) -> str:
    """ros2run's lookup, run in a clean interpreter with the install's environment."""
    code = ('import os, sys; from ament_index_python.packages import get_package_prefix; '
            f'print(os.path.join(get_package_prefix("{PKG}"), "lib", "{PKG}", sys.argv[1]))')
    out = subprocess.run([sys.executable, '-c', code, exe], env=_env(install),
                         capture_output=True, text=True, timeout=60, cwd='/')
    assert out.returncode == 0, out.stderr
    return out.stdout.strip()


def test_ament_index_marker_and_share(install):
    prefix = install / PKG
    assert (prefix / 'share/ament_index/resource_index/packages' / PKG).is_file()
    share = prefix / 'share' / PKG
    assert (share / 'package.xml').is_file()
    assert (share / 'config' / 'params.yaml').is_file()
    assert (share / 'robots' / 'two_link_planar.urdf').is_file()


@pytest.mark.parametrize('exe', EXECUTABLES)
def test_executables_resolve_through_ament_index(install, exe):
    path = Path(_resolve(install, exe))
    assert path == install / PKG / 'lib' / PKG / exe
    assert path.is_file() and os.access(path, os.X_OK)


def test_paper_runs_from_install(install, tmp_path):
    exe = _resolve(install, 'paper')
    proc = subprocess.run([exe, '--duration', '6', '--out', str(tmp_path)], env=_env(install),
                          capture_output=True, text=True, timeout=300, cwd='/')
    assert proc.returncode == 0, proc.stderr
    metrics = json.loads((tmp_path / 'metrics.json').read_text())
    # paper's default theta_hat(0) is half the masses: 32 ms off the surface at the very start
    assert metrics['contact_lost_window_s'] == 0.0 and metrics['contact_lost_s'] <= 0.05
    assert all((tmp_path / f).stat().st_size > 0
               for f in ('fig3_position.png', 'fig4_force.png', 'fig5_parameters.png'))


def test_nodes_start_from_install(install, tmp_path):
    """Controller and sim started through their installed paths join the ROS graph."""
    domain = int(DOMAIN_ID)
    procs = []
    for exe in ('sim', 'controller'):
        proc = NodeProcess(exe, tmp_path / f'{exe}.log', domain, params_file=None,
                           env=_env(install), cwd=Path('/'))
        proc.command_override = [_resolve(install, exe)]
        procs.append(proc)
    spun = Spun(domain)
    try:
        probe = spun.node('build_probe')
        for proc in procs:
            proc.start()
        wait_for(lambda: {'sim', PKG} <= set(probe.get_node_names()), 'both nodes in the graph',
                 timeout=60.0, alive=procs)
    finally:
        for proc in procs:
            proc.stop()
        spun.close()
