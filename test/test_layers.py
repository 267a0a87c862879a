"""
The layer rule and the groups inside each layer, derived from the tree.

Layers: core <- tools <- ros (and sim_node).

* ``core/`` imports only the standard library, numpy, pinocchio and ``core`` itself, and numba
  in ``core/law/*kernels.py``, ``core/runtime/tick_kernels.py`` and
  ``core/offline/plant_kernels.py`` alone (the compiled tick
  and plant, imported when ``tick_impl`` or ``plant_impl`` is compiled: the Python ones never
  load numba);
* ``tools/`` imports the standard library, numpy, rosbags, matplotlib, ``core`` and ``tools``
  (never rclpy or a ROS message package);
* only ``ros/`` and ``sim_node/`` import rclpy;
* only ``sim_node/mujoco_scene.py`` and ``sim_node/mujoco_plant.py`` import ``mujoco`` (the
  sim's ``physics:=mujoco``; sim_node/plants.py imports the plant lazily, so the default sim
  and every other module never load it); no tools/ or ros/ module does.

Groups inside ``core/`` (docs/design.md opens with the map), each importing only the groups
before it: ``model`` (numpy and pinocchio only) <- ``config`` (pure numpy) <- ``law`` <-
``runtime`` <- ``offline``. So the law never imports the runtime, and nothing that runs on a
robot imports the offline plant. Inside ``ros/``: ``common`` <- ``controller`` <- ``programs``
(what a user runs) <- ``lab`` (the instruments: benches, injectors, meters); the sim node's
modules import ``ros.common`` only.

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
    'core': STDLIB | {'numpy', 'pinocchio', 'numba'},
    'tools': STDLIB | {'numpy', 'rosbags', 'matplotlib'},
}
ALLOWED_LAYERS = {'core': {'core'}, 'tools': {'core', 'tools'}}
CORE_GROUPS = ('model', 'config', 'law', 'runtime', 'offline')  # each imports those before it
ROS_GROUPS = ('common', 'controller', 'programs', 'lab')
EXT_OF_GROUP = {'model': STDLIB | {'numpy', 'pinocchio'}, 'config': STDLIB | {'numpy'}}


def _modules(layer: str) -> list[Path]:
    return sorted((PKG / layer).rglob('*.py'))


def _package(path: Path) -> list[str]:
    """Return the dotted package of a module file, as parts."""
    return list(path.relative_to(ROOT).parent.parts)


def _imports(path: Path, package: list[str] | None = None) -> list[str]:
    """Return the dotted name of everything ``path`` imports (relative imports resolved)."""
    package = _package(path) if package is None else package
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                out.append(node.module)
            else:
                base = package[:len(package) - (node.level - 1)]
                out.append('.'.join(base + ([node.module] if node.module else [])))
    return out


def _where(name: str) -> tuple[str, str]:
    """('ext', top package) or (layer, group) of an imported dotted name ('' when no group)."""
    parts = name.split('.')
    if parts[0] != 'hybrid_force_controller':
        return 'ext', parts[0]
    layer = parts[1] if len(parts) > 1 else '?'
    group = parts[2] if len(parts) > 3 and layer in ('core', 'ros') else ''
    return layer, group


def test_the_layers_and_groups_exist_and_hold_every_module():
    for layer in ('core', 'ros', 'tools'):
        assert len(_modules(layer)) > 2, layer
    top = sorted(p.name for p in PKG.glob('*.py'))
    assert top == ['__init__.py'], f'modules outside a layer folder: {top}'
    for layer, groups in (('core', CORE_GROUPS), ('ros', ROS_GROUPS)):
        loose = sorted(p.name for p in (PKG / layer).glob('*.py') if p.name != '__init__.py')
        assert loose == [], f'{layer}/ modules outside a group folder: {loose}'
        folders = sorted(p.name for p in (PKG / layer).iterdir()
                         if p.is_dir() and p.name != '__pycache__')
        assert folders == sorted(groups)
        for group in groups:
            assert (PKG / layer / group / '__init__.py').read_text().strip(), group


@pytest.mark.parametrize('layer', ['core', 'tools'])
def test_layer_imports_only_what_it_may(layer):
    bad = []
    for path in _modules(layer):
        for name in _imports(path):
            kind, what = _where(name)
            ok = (what in ALLOWED[layer]) if kind == 'ext' else (kind in ALLOWED_LAYERS[layer])
            if not ok:
                bad.append(f'{path.relative_to(ROOT)}: {name}')
    assert bad == []


def _group_violations(path: Path, layer: str, groups: tuple[str, ...], group: str,
                      package: list[str] | None = None) -> list[str]:
    """Return what ``path`` (a module of ``layer/group``) imports that its group may not."""
    allowed = set(groups[:groups.index(group) + 1])
    bad = []
    for name in _imports(path, package):
        kind, what = _where(name)
        if kind == layer and what not in allowed:
            bad.append(f'{path.name}: {name}')
        elif kind == 'ext' and group in EXT_OF_GROUP and what not in EXT_OF_GROUP[group]:
            bad.append(f'{path.name}: {name}')
        elif layer == 'core' and group == 'model' and kind == 'core' and what != 'model':
            bad.append(f'{path.name}: {name}')
    return bad


@pytest.mark.parametrize('layer, groups', [('core', CORE_GROUPS), ('ros', ROS_GROUPS)])
def test_each_group_imports_only_the_groups_before_it(layer, groups):
    """E.g. law/ never imports runtime/ or offline/; model/ imports only numpy and pinocchio."""
    bad = [v for group in groups for path in sorted((PKG / layer / group).rglob('*.py'))
           for v in _group_violations(path, layer, groups, group)]
    assert bad == []


@pytest.mark.parametrize('group, line, reported', [
    ('law', 'from ..runtime.modes import Mode', True),
    ('law', 'from ...core.offline import engine', True),
    ('model', 'from ..config.params import build_params', True),
    ('model', 'import rclpy', True),
    ('config', 'import pinocchio', True),
    ('runtime', 'from ..law.control_law import ControlError', False)])
def test_the_group_rule_reports_a_backward_import(tmp_path, group, line, reported):
    """The rule itself: a backward or foreign import is reported, a forward one is not."""
    module = tmp_path / 'x.py'
    module.write_text(line + '\n')
    package = ['hybrid_force_controller', 'core', group]
    assert bool(_group_violations(module, 'core', CORE_GROUPS, group, package)) == reported


def test_the_sim_node_uses_only_the_common_ros_group():
    """The simulated arm shares message and node plumbing, never the controller's path."""
    bad = [f'{p.name}: {name}' for p in sorted((ROOT / 'sim_node').glob('*.py'))
           if p.name != 'offline_figures.py'  # a program: it reads the demo's settings
           for name in _imports(p) if _where(name)[0] == 'ros' and _where(name)[1] != 'common']
    assert bad == []


def test_rclpy_is_imported_only_by_adapters():
    users = {str(p.relative_to(ROOT)) for p in [*PKG.rglob('*.py'), *(ROOT / 'sim_node').rglob(
        '*.py')] if 'rclpy' in {n.split('.')[0] for n in _imports(p)}}
    assert users, 'no module imports rclpy'
    assert all(u.startswith(('hybrid_force_controller/ros/', 'sim_node/')) for u in users), users


MUJOCO_USERS = {'sim_node/mujoco_scene.py', 'sim_node/mujoco_plant.py'}


def test_numba_is_imported_only_by_the_kernels():
    users = {str(p.relative_to(ROOT)) for p in [*PKG.rglob('*.py'), *(ROOT / 'sim_node').rglob(
        '*.py')] if 'numba' in {n.split('.')[0] for n in _imports(p)}}
    assert users == {f'hybrid_force_controller/core/{name}.py' for name in (
        'law/kernels', 'law/step_kernels', 'law/stiffness_kernels', 'runtime/tick_kernels',
        'offline/plant_kernels')}


_PYTHON_TICK = (
    'from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime as C; '
    'from hybrid_force_controller.core.model.robot_model import RobotModel; '
    'from hybrid_force_controller.core.config.params import build_params; '
    "m = RobotModel.from_urdf(); C(m, build_params(m, {'tick_impl': 'python'}))")
_PYTHON_PLANT = (
    'import numpy as np; from hybrid_force_controller.core.offline.simulator import '
    'ArmSimulator; from hybrid_force_controller.core.model.robot_model import RobotModel; '
    "s = ArmSimulator(RobotModel.from_urdf(), None, np.zeros(2), impl='python'); "
    "s.step(np.zeros(2), 1e-3); assert s.impl == 'python'")


@pytest.mark.parametrize('code', [_PYTHON_TICK, _PYTHON_PLANT], ids=['tick', 'plant'])
def test_the_python_tick_and_plant_do_not_load_numba(code):
    proc = subprocess.run([sys.executable, '-c', f"{code}; import sys; print('numba' in "
                           'sys.modules)'], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().splitlines()[-1] == 'False'


def test_mujoco_is_imported_only_by_the_mujoco_plant():
    users = {str(p.relative_to(ROOT)) for p in [*PKG.rglob('*.py'), *(ROOT / 'sim_node').rglob(
        '*.py')] if 'mujoco' in {n.split('.')[0] for n in _imports(p)}}
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
