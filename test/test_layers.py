"""
The layer rule, derived from the tree: core <- tools <- ros (and sim_node).

* ``core/`` imports only the standard library, numpy, pinocchio and ``core`` itself;
* ``tools/`` imports the standard library, numpy, rosbags, matplotlib, ``core`` and ``tools``
  (never rclpy or a ROS message package);
* only ``ros/`` and ``sim_node/`` import rclpy;
* only ``sim_node/mujoco_scene.py`` and ``sim_node/mujoco_plant.py`` import ``mujoco`` (the
  sim's ``physics:=mujoco``; sim_node/plants.py imports the plant lazily, so the default sim
  and every other module never load it); no tools/ or ros/ module does.

Every import statement of every module is checked (also those inside functions), and a
fresh interpreter that imports every core and tool module must not have loaded rclpy.
"""
from __future__ import annotations

import ast
import json
from pathlib import Path
import subprocess
import sys

import pytest


ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / 'hybrid_force_controller'
STDLIB = set(sys.stdlib_module_names) | {'__future__'}
ALLOWED = {
    'core': STDLIB | {'numpy', 'pinocchio'},
    'tools': STDLIB | {'numpy', 'rosbags', 'matplotlib'},
}
ALLOWED_LAYERS = {'core': {'core'}, 'tools': {'core', 'tools'}}


def _modules(layer: str) -> list[Path]:
    return sorted((PKG / layer).rglob('*.py'))


def _imports(path: Path, layer: str) -> list[tuple[str, str]]:
    """(kind, name) of every import: ('ext', top-level package) or ('layer', layer name)."""
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [('ext', a.name.split('.')[0]) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                top = node.module.split('.')
                if top[0] == 'hybrid_force_controller':
                    out.append(('layer', top[1] if len(top) > 1 else '?'))
                else:
                    out.append(('ext', top[0]))
            elif node.level == 1:
                out.append(('layer', layer))
            else:  # from ..x import: x is the layer
                out.append(('layer', (node.module or '?').split('.')[0]))
    return out


def test_the_layers_exist_and_hold_modules():
    for layer in ('core', 'ros', 'tools'):
        assert len(_modules(layer)) > 2, layer
    top = sorted(p.name for p in PKG.glob('*.py'))
    assert top == ['__init__.py'], f'modules outside a layer folder: {top}'


@pytest.mark.parametrize('layer', ['core', 'tools'])
def test_layer_imports_only_what_it_may(layer):
    bad = []
    for path in _modules(layer):
        for kind, name in _imports(path, layer):
            ok = (name in ALLOWED[layer]) if kind == 'ext' else (name in ALLOWED_LAYERS[layer])
            if not ok:
                bad.append(f'{path.relative_to(ROOT)}: {kind} {name}')
    assert bad == []


def test_rclpy_is_imported_only_by_adapters():
    users = {p.relative_to(ROOT).parts[0] + '/' + p.relative_to(ROOT).parts[1]
             for p in [*PKG.rglob('*.py'), *(ROOT / 'sim_node').rglob('*.py')]
             if ('ext', 'rclpy') in _imports(p, p.parent.name)}
    assert users, 'no module imports rclpy'
    assert all(u.startswith(('hybrid_force_controller/ros', 'sim_node/')) for u in users), users


MUJOCO_USERS = {'sim_node/mujoco_scene.py', 'sim_node/mujoco_plant.py'}


def test_mujoco_is_imported_only_by_the_mujoco_plant():
    users = {str(p.relative_to(ROOT)) for p in [*PKG.rglob('*.py'), *(ROOT / 'sim_node').rglob(
        '*.py')] if ('ext', 'mujoco') in _imports(p, p.parent.name)}
    assert users == MUJOCO_USERS


def test_the_default_sim_does_not_load_mujoco():
    code = ('import sys, sim_node.sim_node, sim_node.plants; '
            "print('mujoco' in sys.modules)")
    proc = subprocess.run([sys.executable, '-c', code], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == 'False'


_SCRIPT = """
import importlib, json, sys
for name in json.loads(sys.argv[1]):
    importlib.import_module(name)
print(json.dumps(sorted(m for m in ('rclpy', 'rosbags', 'matplotlib', 'mujoco')
                        if m in sys.modules)))
"""


@pytest.mark.parametrize('layer, forbidden', [
    ('core', ['matplotlib', 'mujoco', 'rclpy', 'rosbags']), ('tools', ['mujoco', 'rclpy'])])
def test_importing_a_layer_loads_nothing_forbidden(layer, forbidden):
    """A fresh interpreter imports every module of the layer (matplotlib is imported lazily)."""
    names = ['hybrid_force_controller.' + '.'.join(p.relative_to(PKG).with_suffix('').parts)
             for p in _modules(layer) if p.name != '__init__.py']
    proc = subprocess.run([sys.executable, '-c', _SCRIPT, json.dumps(names)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    loaded = json.loads(proc.stdout.strip().splitlines()[-1])
    assert not set(loaded) & set(forbidden), loaded
