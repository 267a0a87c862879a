"""
The MuJoCo plant of ``physics:=mujoco``: the interface of the paper's ``ArmSimulator``.

:class:`MujocoPlant` has ``t``, ``step(tau, dt)``, ``hold(dt)``, ``measure()`` and a settable
``surface``, so the ``sim`` node and the offline engine (core/engine.py) drive it as they drive
the pinocchio plant. The caller passes ``dt`` and the efforts; nothing here reads a clock.
Efforts are applied as ``qfrc_applied`` (held over the period, ``substeps`` MuJoCo steps of
``dt / substeps``); the locked joints are welded (mujoco_scene.py).

The measurement is the paper plant's: ``f_W`` is what the wrist sensor reads, given as the force
the tool would exert in the base frame (``f_W = -R_W_ee F_S``, so that
``sensor_wrench_from_f_W(R_W_ee, f_W)`` is the published reading ``F_S``). ``F_S`` is the force
the environment and gravity exert on the tool in the end-effector frame, as a real wrist sensor
reports it: out of contact it is the tool's weight ``m R^T g``; a controller subtracts it
(``tool_mass``). ``f_true_W`` is MuJoCo's contact force, tool on surface (normal and friction),
base frame. ``torque_S`` is the sensor's torque, same convention. With the brakes on (before
the first command, :meth:`hold`) the readings are those of the arm at rest (inverse dynamics
with zero acceleration).
"""
from __future__ import annotations

import math
from pathlib import Path

from hybrid_force_controller.core.contact import in_contact
from hybrid_force_controller.core.environment import ElasticSurface
from hybrid_force_controller.core.robot_model import RobotModel
from hybrid_force_controller.core.simulator import Measurement, SimulatorError
import mujoco
import numpy as np

from .mujoco_params import MujocoOptions
from .mujoco_scene import build_scene, check_surface, set_surface

__all__ = ['MujocoPlant']


class MujocoPlant:
    """
    The arm, tool and surface in MuJoCo, stepped by the caller.

    ``surface`` None starts without contact; ``stiffness`` then sizes the table top for the
    surface enabled later (run-time stiffness changes: up to 4 times the start-up one).
    """

    def __init__(self, model: RobotModel, urdf: str | Path, opts: MujocoOptions,
                 surface: ElasticSurface | None, q0: np.ndarray, *, dt: float = 1e-3,
                 substeps: int = 1, theta: np.ndarray | None = None,
                 noise_sigma: float = 0.0, seed: int = 0,
                 stiffness: float | None = None) -> None:
        if substeps < 1:
            raise SimulatorError('substeps must be >= 1')
        self.n, self.substeps = model.n, int(substeps)
        # the stiffness sizes the table top (mujoco_scene.py); without a surface at start-up,
        # the one it will have when enabled
        k0 = surface.k if surface is not None else stiffness or 1.0
        self.scene = build_scene(urdf, model, opts, dt / self.substeps, k0, theta)
        self.m, self.d = self.scene.model, mujoco.MjData(self.scene.model)
        self.surface = surface
        q0 = np.asarray(q0, dtype=float)
        if q0.shape != (self.n,):
            raise SimulatorError(f'initial state must have {self.n} joints')
        self.d.qpos[self.scene.qpos] = q0
        self.noise_sigma = float(noise_sigma)
        self.rng = np.random.default_rng(seed)
        self.t = 0.0
        self.tau = np.zeros(self.n)
        self.torque_S = np.zeros(3)
        self._braked = True
        self._tau_c = None  # the sim node clears it on a surface change (ArmSimulator's cache)
        self._force6 = np.zeros(6)

    @property
    def surface(self) -> ElasticSurface | None:
        """Return the current plane: pose and stiffness; None when contact is disabled."""
        return self._surface

    @surface.setter
    def surface(self, surface: ElasticSurface | None) -> None:
        set_surface(self.scene, self.d, surface)
        self._surface = surface

    def check_surface(self, surface: ElasticSurface) -> None:
        """Raise SurfaceError when ``surface`` cannot be set (the sim node validates with it)."""
        check_surface(self.scene, surface)

    @property
    def q(self) -> np.ndarray:
        return self.d.qpos[self.scene.qpos].copy()

    @property
    def qdot(self) -> np.ndarray:
        return self.d.qvel[self.scene.dof].copy()

    def step(self, tau: np.ndarray, dt: float) -> Measurement:
        """Advance ``dt`` seconds with the efforts ``tau`` held constant."""
        tau = np.asarray(tau, dtype=float)
        if tau.shape != (self.n,) or not math.isfinite(tau.sum()):
            raise SimulatorError(f'effort must be {self.n} finite values, got {tau}')
        if not (dt > 0.0 and math.isfinite(dt)):
            raise SimulatorError(f'dt must be finite and > 0, got {dt}')
        h = dt / self.substeps
        if self.m.opt.timestep != h:
            self.m.opt.timestep = h
        self.tau = tau.copy()
        self.d.qfrc_applied[self.scene.dof] = tau
        mujoco.mj_step(self.m, self.d, self.substeps)
        self._braked = False
        self.t += dt
        return self.measure()

    def hold(self, dt: float) -> Measurement:
        """Advance ``dt`` seconds with the arm held still by its brakes (before a command)."""
        self.d.qvel[:] = 0.0
        self._braked = True
        self.t += dt
        return self.measure()

    def measure(self) -> Measurement:
        """Sensor readings at the current state (noise drawn from the seeded generator)."""
        m, d, sc = self.m, self.d, self.scene
        if self._braked:  # at rest: the brakes take the torques, nothing accelerates
            d.qvel[:] = 0.0
            d.qacc[:] = 0.0
            mujoco.mj_inverse(m, d)
        else:
            mujoco.mj_forward(m, d)
        sensor = d.sensordata
        a_f, a_t = sc.force_adr, sc.torque_adr
        self.torque_S = -sensor[a_t:a_t + 3]
        p_W, R_W_ee = d.xpos[sc.ee_body].copy(), d.xmat[sc.ee_body].reshape(3, 3).copy()
        # MuJoCo's force sensor reads the force the hand exerts on the tool (site frame): minus
        # the published F_S, so f_W = -R F_S is R times the reading
        f_W = R_W_ee @ sensor[a_f:a_f + 3]
        f_true = self._contact_force_root() if d.ncon else np.zeros(3)
        if sc.rotated:  # base_link is not the URDF root
            R = sc.R_W_root
            p_W, R_W_ee, f_W, f_true = R @ p_W + sc.o_W, R @ R_W_ee, R @ f_W, R @ f_true
        if self.noise_sigma:
            f_W = f_W + self.rng.normal(0.0, self.noise_sigma, 3)
        f_n = math.sqrt(f_true @ f_true)
        return Measurement(self.t, d.qpos[sc.qpos], d.qvel[sc.dof], self.tau, p_W, R_W_ee, f_W,
                           f_true, in_contact(f_n))

    def _contact_force_root(self) -> np.ndarray:
        """Force the tool exerts on the surface, MuJoCo world (the URDF root)."""
        d, f, tool = self.d, np.zeros(3), self.scene.tool_geom
        for i in range(d.ncon):
            mujoco.mj_contactForce(self.m, d, i, self._force6)
            contact = d.contact[i]
            # the force geom1 exerts on geom2, in the contact frame (normal from 1 to 2)
            on_2 = contact.frame.reshape(3, 3).T @ self._force6[:3]
            f += on_2 if contact.geom1 == tool else -on_2
        return f
