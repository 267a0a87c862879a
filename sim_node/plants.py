"""
The sim's plant from its validated parameters: ``physics`` picks the paper's or MuJoCo's.

``mujoco`` is imported here only when ``physics:=mujoco``, so the default sim does not load it.
Both plants have the interface the sim node and the offline engine drive (``t``, ``step``,
``hold``, ``measure``, a settable ``surface``).
"""
from __future__ import annotations

import math
from typing import Any, Callable

from hybrid_force_controller.core.config.params import ParameterValidationError
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.environment import Surface
from hybrid_force_controller.core.offline.plant_compiled import plant_kernels_cached
from hybrid_force_controller.core.offline.simulator import ArmSimulator, PLANT_IMPLS
import numpy as np

from .mujoco_params import check_physics, DISC_HALF_THICKNESS_M, mujoco_options

__all__ = ['make_plant', 'touch_offset']


def touch_offset(v: dict[str, Any], axis_W: np.ndarray | None = None
                 ) -> Callable[[np.ndarray], float]:
    """
    Return ``reach(n_W)``: from the end-effector origin to a surface that touches the tool, m.

    ``n_W`` is the surface's unit normal; the tool is at its start pose.
    0 on the paper's physics (a point tool); on MuJoCo the sphere's radius, and for a disc of
    radius r and half thickness h whose axis is ``axis_W`` (the start's end-effector z, base
    frame) its support along n, ``r sqrt(1 - c^2) + h c`` with ``c = |axis_W . n_W|``.
    """
    if check_physics(v['physics']) != 'mujoco':
        return lambda n_W: 0.0
    r = float(v['tool_radius'])
    if v.get('tool_shape', 'sphere') != 'disc' or axis_W is None:
        return lambda n_W: r
    a = np.asarray(axis_W, dtype=float)

    def disc(n_W: np.ndarray) -> float:
        c = min(abs(float(a @ n_W)), 1.0)
        return r * math.sqrt(1.0 - c * c) + DISC_HALF_THICKNESS_M * c
    return disc


def make_plant(v: dict[str, Any], model: RobotModel, urdf: str,
               surface: Surface | None, q0: np.ndarray,
               log: Callable[[str], Any] | None = None) -> Any:
    """
    Build the plant of the sim's parameter values ``v`` (SIM_SCHEMA names).

    ``log`` is told before a first compile of the compiled plant's kernels.

    Raises ParameterValidationError for a bad physics or MuJoCo option.
    """
    if check_physics(v['physics']) == 'paper':
        if v.get('tool_shape', 'sphere') != 'sphere':
            raise ParameterValidationError(
                f"tool_shape {v['tool_shape']!r} needs physics:=mujoco: the paper's physics "
                'models a point tool (no rim, no contact moment)')
        plant = model.with_theta(v['masses']) if v['masses'] else model
        if v['plant_impl'] not in PLANT_IMPLS:
            raise ParameterValidationError(f'plant_impl must be one of {list(PLANT_IMPLS)}, '
                                           f"got {v['plant_impl']!r}")
        if v['plant_impl'] == 'compiled' and not plant_kernels_cached() and log is not None:
            log('compiling the plant (numba kernels, about 5-10 s, once: cached for the next '
                'starts)')
        return ArmSimulator(plant, surface, q0, substeps=v['substeps'],
                            noise_sigma=v['noise_sigma'], seed=v['seed'], impl=v['plant_impl'])
    from .mujoco_plant import MujocoPlant
    theta = np.asarray(v['masses'], dtype=float) if v['masses'] else None
    return MujocoPlant(model, urdf, mujoco_options(v), surface, q0, dt=1.0 / v['rate_hz'],
                       substeps=v['substeps'], theta=theta, noise_sigma=v['noise_sigma'],
                       seed=v['seed'], stiffness=v['stiffness'], shape=v['surface_shape'])
