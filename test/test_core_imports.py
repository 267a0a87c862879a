"""The core (non-ROS) modules import without rclpy, rosbags or matplotlib.

Runs in a fresh interpreter so that modules already imported by other tests do not hide
an unwanted dependency. Only the core modules that exist when the test runs are imported
(``importlib.util.find_spec``); ``robot_model`` must always be among them.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

PACKAGE = 'hybrid_force_controller'
CORE_MODULES = [f'{PACKAGE}.{name}' for name in
                ['robot_model', 'parameter_sets', 'params', 'control_law', 'environment',
                 'simulator', 'reference', 'filters', 'analysis', 'runtime', 'scenario',
                 'arm7', 'loop_stats']]
FORBIDDEN = ['rclpy', 'rosbags', 'matplotlib']
REPO_ROOT = Path(__file__).resolve().parent.parent

_SCRIPT = """
import importlib, importlib.util, json, sys
imported = []
for name in json.loads(sys.argv[1]):
    if importlib.util.find_spec(name) is not None:
        importlib.import_module(name)
        imported.append(name)
loaded = [m for m in json.loads(sys.argv[2]) if m in sys.modules]
print(json.dumps({'imported': imported, 'forbidden_loaded': loaded}))
"""


def test_core_modules_import_without_ros_or_plotting():
    """Importing every existing core module pulls in none of rclpy, rosbags, matplotlib."""
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join(
        [str(REPO_ROOT)] + ([env['PYTHONPATH']] if env.get('PYTHONPATH') else []))
    proc = subprocess.run(
        [sys.executable, '-c', _SCRIPT, json.dumps(CORE_MODULES), json.dumps(FORBIDDEN)],
        cwd=REPO_ROOT, env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, f'import failed:\n{proc.stderr}'
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert f'{PACKAGE}.robot_model' in result['imported'], result
    assert result['forbidden_loaded'] == [], (
        f"core modules {result['imported']} imported {result['forbidden_loaded']}")
