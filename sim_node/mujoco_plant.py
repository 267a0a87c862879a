"""
The MuJoCo plant of ``physics:=mujoco``: the interface of the paper's ``ArmSimulator``.

:class:`MujocoPlant` has ``t``, ``step(tau, dt)``, ``hold(dt)``, ``measure()`` and a settable
``surface``, so the ``sim`` node and the offline engine (core/offline/engine.py) drive it as they
drive the pinocchio plant. The caller passes ``dt`` and the efforts; nothing here reads a clock.
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

from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.environment import Surface
from hybrid_force_controller.core.offline.simulator import Measurement, SimulatorError
from hybrid_force_controller.core.runtime.contact import in_contact
import mujoco
import numpy as np

from .mujoco_params import MujocoOptions
from .mujoco_scene import build_scene, check_surface, set_surface, surface_shift

# mj_step's integrator after its mj_forward, by opt.integrator (RK4 evaluates the dynamics
# four times: it keeps the full mj_step)
_INTEGRATORS = {int(mujoco.mjtIntegrator.mjINT_EULER): mujoco.mj_Euler,
                int(mujoco.mjtIntegrator.mjINT_IMPLICIT): mujoco.mj_implicit,
                int(mujoco.mjtIntegrator.mjINT_IMPLICITFAST): mujoco.mj_implicit}

_STAGE_VEL = mujoco.mjtStage.mjSTAGE_VEL

__all__ = ['MujocoPlant']


class MujocoPlant:
    """
    The arm, tool and surface in MuJoCo, stepped by the caller.

    ``surface`` None starts without contact; ``stiffness`` and ``shape`` then size the table top
    and choose its shape for the surface enabled later (run-time stiffness changes: up to 4 times
    the start-up one; the shape is the start-up one for good).
    """

    def __init__(self, model: RobotModel, urdf: str | Path, opts: MujocoOptions,
                 surface: Surface | None, q0: np.ndarray, *, dt: float = 1e-3,
                 substeps: int = 1, theta: np.ndarray | None = None,
                 noise_sigma: float = 0.0, seed: int = 0,
                 stiffness: float | None = None, shape: str = 'plane') -> None:
        if substeps < 1:
            raise SimulatorError('substeps must be >= 1')
        self.n, self.substeps = model.n, int(substeps)
        # the stiffness sizes the table top (mujoco_scene.py); without a surface at start-up,
        # the one it will have when enabled
        k0 = surface.k if surface is not None else stiffness or 1.0
        shape = surface.shape if surface is not None else shape
        self.scene = build_scene(urdf, model, opts, dt / self.substeps, k0, theta, shape)
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
        # measure() computed every stage at the current state (step() reuses it; measure sets it)
        self._forwarded = False
        self._integrate = _INTEGRATORS.get(int(self.m.opt.integrator))  # None: full mj_step
        self.reuse_forward = True  # False: a full mj_step every step (the reference, tests)
        self._tau_c = None  # the sim node clears it on a surface change (ArmSimulator's cache)
        self._h = self.m.opt.timestep
        self._bind_views()

    def _bind_views(self) -> None:
        """
        Make once the views into MjData that step() and measure() read and write.

        MjData's arrays never move, and each attribute access would build a new view: at
        1 kHz the glue cost more than MuJoCo itself.
        """
        d, sc = self.d, self.scene
        self._qpos, self._qvel, self._qfrc_applied = d.qpos, d.qvel, d.qfrc_applied
        self._F_sensor = d.sensordata[sc.force_adr:sc.force_adr + 3]
        self._T_sensor = d.sensordata[sc.torque_adr:sc.torque_adr + 3]
        self._p_ee, self._R_ee = d.xpos[sc.ee_body], d.xmat[sc.ee_body].reshape(3, 3)
        # the force on the table top (cfrc_ext: contacts, no applied force on it), MuJoCo world
        self._f_plate = d.cfrc_ext[sc.plate, 3:6]

    @property
    def surface(self) -> Surface | None:
        """Return the current plane: pose and stiffness; None when contact is disabled."""
        return self._surface

    @surface.setter
    def surface(self, surface: Surface | None) -> None:
        set_surface(self.scene, self.d, surface)
        self._surface = surface
        self._forwarded = False  # the table moved: the position stage is stale

    def check_surface(self, surface: Surface) -> None:
        """Raise SurfaceError when ``surface`` cannot be set (the sim node validates with it)."""
        check_surface(self.scene, surface)

    def contact_normal(self, p_W: np.ndarray) -> np.ndarray | None:
        """
        Return the unit normal into the surface nearest the tool's centre ``p_W``, base frame.

        The surface as it is now: moved on its spring (the deflection the last measure() saw).
        None without a surface.
        """
        s = self._surface
        return None if s is None else s.normal_at(p_W - surface_shift(self.scene, self.d))

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
        if h != self._h:
            self.m.opt.timestep = self._h = h
        self.tau = tau.copy()
        self._qfrc_applied[self.scene.dof] = tau
        rest = self.substeps
        if self._forwarded and self._integrate is not None and self.reuse_forward:
            # measure() ran the position and velocity stages at this very state: mj_step's
            # own mj_forward would repeat them. Only the acceleration stage (the new tau)
            # runs, then mj_step's integrator: the same numbers, about one forward less.
            mujoco.mj_forwardSkip(self.m, self.d, _STAGE_VEL, 1)
            self._integrate(self.m, self.d)
            rest -= 1
        if rest:
            mujoco.mj_step(self.m, self.d, rest)
        self._braked = False
        self.t += dt
        return self.measure()

    def hold(self, dt: float) -> Measurement:
        """Advance ``dt`` seconds with the arm held still by its brakes (before a command)."""
        self._braked = True  # measure() zeroes the velocity
        self.t += dt
        return self.measure()

    def measure(self) -> Measurement:
        """Sensor readings at the current state (noise drawn from the seeded generator)."""
        m, d, sc = self.m, self.d, self.scene
        if self._braked:  # at rest: the brakes take the torques, nothing accelerates
            self._qvel[:] = 0.0
            d.qacc[:] = 0.0
            mujoco.mj_inverse(m, d)
        else:
            mujoco.mj_forward(m, d)
        self.torque_S = -self._T_sensor
        p_W, R_W_ee = self._p_ee.copy(), self._R_ee.copy()
        # MuJoCo's force sensor reads the force the hand exerts on the tool (site frame): minus
        # the published F_S, so f_W = -R F_S is R times the reading
        f_W = R_W_ee @ self._F_sensor
        # the force the tool exerts on the surface is the one the table top feels (cfrc_ext)
        f_true = self._f_plate.copy()
        if sc.rotated:  # base_link is not the URDF root
            R = sc.R_W_root
            p_W, R_W_ee, f_W, f_true = R @ p_W + sc.o_W, R @ R_W_ee, R @ f_W, R @ f_true
        if self.noise_sigma:
            f_W = f_W + self.rng.normal(0.0, self.noise_sigma, 3)
        f_n = math.sqrt(f_true @ f_true)
        self._forwarded = not self._braked  # mj_forward ran every stage at this state
        return Measurement(self.t, self._qpos[sc.qpos], self._qvel[sc.dof], self.tau, p_W,
                           R_W_ee, f_W, f_true, in_contact(f_n))
