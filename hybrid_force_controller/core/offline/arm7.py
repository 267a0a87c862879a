"""
The 7-DOF demonstration: a Franka Panda pressing 5 N on a tilted plane (pure core).

The end effector (``panda_hand_tcp``) presses ``f_d = 5`` N on a plane tilted 0.3 rad about
the base x axis while it tracks a 10 cm line on it (``x_d = c + 0.05 sin t`` along x); the
controller starts with the link masses off by +/-30 %. The URDF is the bundled, mesh-free
copy of example-robot-data's Panda (``robots/panda.urdf``, Apache-2.0).
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path

import numpy as np

from .engine import Event
from .scenario import ScenarioConfig
from ..law.path import follow_basis, PathLimits, plan_path
from ..model.robot_model import RobotModel

__all__ = ['PANDA_JOINTS', 'PANDA_Q0', 'panda_model', 'panda_scenario', 'panda_urdf_path',
           'square_path_event']

PANDA_JOINTS = tuple(f'panda_joint{i}' for i in range(1, 8))
PANDA_Q0 = (0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8)
TILT_RAD = 0.3
MASS_ERROR = (1.3, 0.7, 1.3, 0.7, 1.3, 0.7, 1.3)  # theta_hat(0) / true masses


def panda_urdf_path() -> Path:
    """Return the path of the bundled Panda URDF (kinematics and inertias, no meshes)."""
    return Path(str(resources.files('hybrid_force_controller') / 'robots' / 'panda.urdf'))


def panda_model(parameter_set: str = 'link_masses') -> RobotModel:
    """Load the Panda: 7 arm joints (fingers locked), z up, task frame ``panda_hand_tcp``."""
    return RobotModel.from_urdf(panda_urdf_path(), end_effector_link='panda_hand_tcp',
                                joints=PANDA_JOINTS, gravity_root=(0.0, 0.0, -9.81),
                                parameter_set=parameter_set)


def panda_scenario(model: RobotModel, duration: float = 20.0, **kwargs) -> ScenarioConfig:
    """Return the scenario config; the line is centred under the start position of the tool."""
    p0 = model.kinematics(np.array(PANDA_Q0), np.zeros(model.n)).p_W
    n = [0.0, np.sin(TILT_RAD), -np.cos(TILT_RAD)]
    overrides = {'n': n, 'f_d': 5.0, 'ref_center': p0.tolist(),
                 'ref_amplitude': [0.05, 0.0, 0.0], 'ref_omega': 1.0,
                 **kwargs.pop('overrides', {})}
    return ScenarioConfig(k=3000.0, duration=duration, q0=PANDA_Q0,
                          theta_hat0_scale=MASS_ERROR, overrides=overrides, **kwargs)


def square_path_event(t: float, side: float, sent: dict | None = None) -> Event:
    """
    Return an event that sends an untimed square path at ``t`` (s), as the node would.

    The square of ``side`` (m) lies in the surface's tangent plane, centred on the reference
    at ``t``, planned from the reference's position and velocity with the runtime's
    ``path_*`` parameters. ``sent`` (optional) receives the plan and the time.
    """
    def follow(rt, plant) -> None:
        n_W, r = rt.params.law.n, rt.params.runtime
        x0, v0 = rt.reference(plant.t)[:2]
        corners = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [0, 0]]) * side - side / 2
        points = x0 + corners @ follow_basis(n_W, rt.model.task_axes).T
        limits = PathLimits(r.path_speed, r.path_max_accel, r.path_max_speed,
                            r.path_max_poses, r.path_corner_tolerance)
        plan = plan_path(points, np.zeros(len(points)), x0, n_W, rt.model.task_axes, limits,
                         start_v_W=v0)
        rt.on_path(plan, 1)
        if sent is not None:
            sent.update(plan=plan, t=plant.t)
    return Event(t, follow)
