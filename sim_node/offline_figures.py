"""
``python -m sim_node.offline_figures``: the demo's scenarios offline, on each physics, as JSON.

Reads the same config files as ``demo`` (config/params.yaml or panda_params.yaml +
panda_table.yaml, then mujoco.yaml and demo's tool mass for ``physics:=mujoco``), builds the
controller's runtime and the sim's plant from them as the nodes do (sim_node/plants.py), and
runs the offline engine (core/offline/engine.py) with the timing measured over DDS
(``TimingModel.ros_measured``, seeded), so the figures do not depend on the machine's load:
RMS tangential position and true-force errors over t >= 5 s, the contact lost after the first
touch, and the plant's cost per 1 ms step (``plant_step_us``: step + measure, wall time of this
process).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
import sys
import time
from typing import Any, Sequence

from hybrid_force_controller.core.config.params import (build_params, CONTROLLER_SCHEMA,
                                                        MODEL_SCHEMA)
from hybrid_force_controller.core.model.robot_model import default_urdf_path, RobotModel
from hybrid_force_controller.core.offline.arm7 import panda_urdf_path
from hybrid_force_controller.core.offline.engine import run_loop
from hybrid_force_controller.core.offline.environment import ElasticSurface
from hybrid_force_controller.core.offline.timing import TimingModel
from hybrid_force_controller.core.runtime.contact import in_contact
from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime
from hybrid_force_controller.ros.programs.demo import TOOL_MASS
import numpy as np

from .plants import make_plant, touch_offset
from .sim_node import SIM_SCHEMA

__all__ = ['main', 'run']

CONFIG = Path(__file__).resolve().parents[1] / 'config'
STEP_COST_STEPS = 2000


def _values(files: Sequence[str], node: str) -> dict[str, Any]:
    import yaml
    out: dict[str, Any] = {}
    for name in files:
        out.update(yaml.safe_load((CONFIG / name).read_text()).get(node, {})
                   .get('ros__parameters', {}))
    return out


def run(arm: str, physics: str, friction: float, duration: float = 20.0,
        seed: int = 1, tool_mass: float | None = None) -> dict[str, float]:
    """Run one scenario offline; return its figures."""
    files = ['params.yaml'] if arm == 'paper' else ['panda_params.yaml', 'panda_table.yaml']
    files += ['mujoco.yaml'] if physics == 'mujoco' else []
    extra = {} if arm == 'paper' else {'robot_description': str(panda_urdf_path())}
    ctrl, sim = _values(files, 'hybrid_force_controller'), _values(files, 'sim')
    v = {s.name: s.default for s in (*SIM_SCHEMA, *MODEL_SCHEMA)}
    mass = TOOL_MASS[arm] if tool_mass is None else tool_mass
    tool = {'tool_mass': mass} if physics == 'mujoco' else {}  # as demo passes it
    ctrl.update(tool)
    v.update({**sim, **extra, **tool, 'physics': physics, 'surface_friction': friction})
    model = RobotModel.from_parameters(v, v['joints'])
    names = {s.name for s in CONTROLLER_SCHEMA}
    runtime = ControllerRuntime(model, build_params(model, {k: x for k, x in ctrl.items()
                                                            if k in names}))
    q0 = np.asarray(v['q0'], dtype=float)
    n = np.asarray(v['surface_normal'], dtype=float) / np.linalg.norm(v['surface_normal'])
    kin0 = model.kinematics(q0, np.zeros(model.n))  # the sim's default: touching at start
    reach = touch_offset(v, kin0.R_W_ee[:, 2])(n)
    surface = ElasticSurface.create(v['stiffness'], kin0.p_W + reach * n, n)
    plant = make_plant(v, model, _urdf_text(v), surface, q0)
    log = run_loop(runtime, plant, duration, TimingModel.ros_measured(seed=seed))
    n_W, f_d = runtime.params.law.n, runtime.params.law.f_d
    f_n = log.f_true_W @ n_W
    after = log.t >= 5.0
    P_t = np.eye(3) - np.outer(n_W, n_W)
    e_x = (log.x_W - log.x_d_W)[after] @ P_t
    touch = next((i for i, f in enumerate(f_n) if in_contact(f)), len(f_n))
    lost = [not in_contact(f) for f in f_n[touch:]]
    tau, t0 = log.tau[-1], time.perf_counter()
    for _ in range(STEP_COST_STEPS):  # the plant's cost: step + measure, the last effort held
        plant.step(tau, 1e-3)
    step_us = (time.perf_counter() - t0) / STEP_COST_STEPS * 1e6
    return {'plant_step_us': step_us,
            'rms_position_error_m': float(np.sqrt(np.mean(np.sum(e_x ** 2, axis=1)))),
            'rms_force_error_n': float(np.sqrt(np.mean((f_n[after] - f_d) ** 2))),
            'max_force_error_n': float(np.max(np.abs(f_n[after] - f_d))),
            'contact_lost_after_touch_s': float(np.sum(lost) * 1e-3),
            'contact_lost_after_5s_s': float(np.sum([not in_contact(f) for f in f_n[after]])
                                             * 1e-3)}


def _urdf_text(v: dict[str, Any]) -> str:
    src = v['robot_description']
    return Path(src).read_text() if src else default_urdf_path().read_text()


def main(argv: Sequence[str] | None = None) -> int:
    """Print the figures of the requested scenarios as JSON."""
    ap = argparse.ArgumentParser(prog='offline_figures', description=__doc__.splitlines()[1])
    ap.add_argument('--arm', choices=('paper', 'panda'), default='paper')
    ap.add_argument('--physics', nargs='+', default=['paper', 'mujoco'])
    ap.add_argument('--friction', type=float, default=None)
    ap.add_argument('--duration', type=float, default=20.0)
    ap.add_argument('--seed', type=int, default=1)
    ap.add_argument('--tool-mass', type=float, default=None, help='mujoco: as demo')
    args = ap.parse_args(argv)
    mu = args.friction if args.friction is not None else 0.3 if args.arm == 'panda' else 0.0
    out = {p: run(args.arm, p, mu if p == 'mujoco' else 0.0, args.duration, args.seed,
                  args.tool_mass) for p in args.physics}
    print(json.dumps({'arm': args.arm, 'friction': mu, **out}, indent=2))
    return 0


if __name__ == '__main__':
    sys.exit(main())
