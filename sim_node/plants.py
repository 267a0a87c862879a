"""
The sim's plant from its validated parameters: ``physics`` picks the paper's or MuJoCo's.

``mujoco`` is imported here only when ``physics:=mujoco``, so the default sim does not load it.
Both plants have the interface the sim node and the offline engine drive (``t``, ``step``,
``hold``, ``measure``, a settable ``surface``).
"""
from __future__ import annotations

from typing import Any

from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.environment import Surface
from hybrid_force_controller.core.offline.simulator import ArmSimulator
import numpy as np

from .mujoco_params import check_physics, mujoco_options

__all__ = ['make_plant', 'touch_offset']


def touch_offset(v: dict[str, Any]) -> float:
    """Distance from the end-effector origin to the surface it touches at the start, m."""
    return v['tool_radius'] if check_physics(v['physics']) == 'mujoco' else 0.0


def make_plant(v: dict[str, Any], model: RobotModel, urdf: str,
               surface: Surface | None, q0: np.ndarray) -> Any:
    """
    Build the plant of the sim's parameter values ``v`` (SIM_SCHEMA names).

    Raises ParameterValidationError for a bad physics or MuJoCo option.
    """
    if check_physics(v['physics']) == 'paper':
        plant = model.with_theta(v['masses']) if v['masses'] else model
        return ArmSimulator(plant, surface, q0, substeps=v['substeps'],
                            noise_sigma=v['noise_sigma'], seed=v['seed'])
    from .mujoco_plant import MujocoPlant
    theta = np.asarray(v['masses'], dtype=float) if v['masses'] else None
    return MujocoPlant(model, urdf, mujoco_options(v), surface, q0, dt=1.0 / v['rate_hz'],
                       substeps=v['substeps'], theta=theta, noise_sigma=v['noise_sigma'],
                       seed=v['seed'], stiffness=v['stiffness'], shape=v['surface_shape'])
