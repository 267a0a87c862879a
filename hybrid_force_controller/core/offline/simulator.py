"""
Offline plant: rigid-body arm (pinocchio ABA) against the elastic surface.

The same plant runs inside the ``sim`` node. Pure numpy + pinocchio; the caller passes
``dt`` and the joint efforts, nothing reads a clock.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pinocchio as pin

from .environment import Surface
from .plant_compiled import compiled_plant, surface_array
from ..model.linalg import all_finite
from ..model.robot_model import RobotModel
from ..runtime.contact import in_contact

__all__ = ['ArmSimulator', 'Measurement', 'PLANT_IMPLS', 'SimulatorError']

PLANT_IMPLS = ('compiled', 'python')

_LWA = pin.ReferenceFrame.LOCAL_WORLD_ALIGNED


class SimulatorError(ValueError):
    """Bad simulator input (wrong effort length, non-finite effort, bad state)."""


class Measurement(NamedTuple):
    """
    What the arm's sensors report after a step.

    ``f_W`` is the force the tool exerts on the surface in the base frame as the wrist
    sensor measures it (with noise when configured); ``f_true_W`` is the noise-free value;
    ``in_contact`` is the one contact predicate (contact.py) on the true force.
    """

    t: float
    q: np.ndarray
    qdot: np.ndarray
    tau: np.ndarray
    p_W: np.ndarray
    R_W_ee: np.ndarray
    f_W: np.ndarray
    f_true_W: np.ndarray
    in_contact: bool


class ArmSimulator:
    """
    Semi-implicit Euler integration with ``substeps`` per control period.

    Each sub-step: contact force from the surface, eqs. (12)-(13) of [1] (on a curved surface
    along its local normal, environment.py), mapped to the joints by ``-J_p^T f``, optional
    viscous + Coulomb joint friction (off by default), then ABA. Efforts are held (zero-order
    hold) over the whole period.
    """

    def __init__(self, model: RobotModel, surface: Surface | None, q0: np.ndarray,
                 qdot0: np.ndarray | None = None, *, substeps: int = 4,
                 noise_sigma: float = 0.0, seed: int = 0,
                 friction_viscous: float = 0.0, friction_coulomb: float = 0.0,
                 impl: str = 'compiled') -> None:
        if impl not in PLANT_IMPLS:
            raise SimulatorError(f'plant_impl must be one of {list(PLANT_IMPLS)}, got {impl!r}')
        self.model = model
        # compiled (plant_kernels.py) or the Python reference below; ``impl_note`` says which
        self._compiled, self.impl_note = (compiled_plant(model) if impl == 'compiled' else
                                          (None, 'plant_impl python'))
        self.impl = 'python' if self._compiled is None else 'compiled'
        self.surface = surface
        self.q = np.array(q0, dtype=float)
        self.qdot = np.zeros(model.n) if qdot0 is None else np.array(qdot0, dtype=float)
        if self.q.shape != (model.n,) or self.qdot.shape != (model.n,):
            raise SimulatorError(f'initial state must have {model.n} joints')
        if substeps < 1:
            raise SimulatorError('substeps must be >= 1')
        self.substeps = int(substeps)
        self.noise_sigma = float(noise_sigma)
        self.rng = np.random.default_rng(seed)
        self.friction = (float(friction_viscous), float(friction_coulomb))
        self.t = 0.0
        self.tau = np.zeros(model.n)
        self._tau_c: np.ndarray | None = None  # contact torque at the current q, if known
        self._pin_model, self._pin_data = model.model, model.data

    @property
    def surface(self) -> Surface | None:
        """Return the workpiece the tool presses, None for free motion; set it between steps."""
        return self._surface

    @surface.setter
    def surface(self, surface: Surface | None) -> None:
        self._surface, self._sf = surface, surface_array(surface)
        self._tau_c = None

    def _contact(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple]:
        """
        Contact force on the surface, its joint torque ``-J_p^T f`` and the tool pose.

        All in ``base_link`` (the frame of ``_W`` quantities).
        """
        if self._compiled is not None:
            f_W, tau_c, p_W, R_W = self._compiled.contact(q, self._sf)
            return f_W, tau_c, (p_W, R_W, None)
        m, d, fid = self._pin_model, self._pin_data, self.model.frame_id
        J = pin.computeFrameJacobian(m, d, q, fid, _LWA)[:3]
        T_root_ee = pin.updateFramePlacement(m, d, fid)
        # everything in base_link, the frame of the surface and of the controller
        pose = self.model.base_from_root(T_root_ee.translation, T_root_ee.rotation, J)
        surface = self.surface
        depth = -1.0 if surface is None else surface.penetration(pose[0])
        if depth <= 0.0:  # eqs. (12)-(13): the surface pushes but never pulls
            return np.zeros(3), np.zeros(self.model.n), pose
        f_W = (surface.k * depth) * surface.normal_at(pose[0])  # n_W on the plane
        return f_W, -(pose[2].T @ f_W), pose

    def step(self, tau: np.ndarray, dt: float) -> Measurement:
        """Advance ``dt`` seconds with the efforts ``tau`` held constant."""
        tau = np.asarray(tau, dtype=float)
        if tau.shape != (self.model.n,) or not all_finite(tau):
            raise SimulatorError(f'effort must be {self.model.n} finite values, got {tau}')
        if not (dt > 0.0 and math.isfinite(dt)):
            raise SimulatorError(f'dt must be finite and > 0, got {dt}')
        self.tau = tau.copy()
        h = dt / self.substeps
        if self._compiled is not None:  # the same steps in one call (plant_kernels.py)
            self.q, self.qdot, p_W, R_W_ee, f_true = self._compiled.step(
                self.q, self.qdot, self.tau, h, self.substeps, self.friction, self._sf)
            self._tau_c = None
            self.t += dt
            return self._measurement(f_true, p_W, R_W_ee)
        b, fc = self.friction
        q, qdot = self.q, self.qdot
        for i in range(self.substeps):
            # the first sub-step starts where measure() already evaluated the contact
            tau_c = self._tau_c if i == 0 and self._tau_c is not None else self._contact(q)[1]
            tau_net = tau + tau_c
            if b or fc:
                tau_net = tau_net - (b * qdot + fc * np.tanh(qdot / 1e-3))
            qddot = pin.aba(self._pin_model, self._pin_data, q, qdot, tau_net)
            qdot = qdot + h * qddot
            q = q + h * qdot
        self.q, self.qdot = q, qdot
        self._tau_c = None
        self.t += dt
        return self.measure()

    def hold(self, dt: float) -> Measurement:
        """Advance ``dt`` seconds with the arm held still by its brakes (before a command)."""
        self.qdot = np.zeros(self.model.n)
        self.t += dt
        return self.measure()

    def contact_normal(self, p_W: np.ndarray) -> np.ndarray | None:
        """Return the surface's unit normal (into it) nearest ``p_W``; None without a surface."""
        return None if self.surface is None else self.surface.normal_at(p_W)

    def measure(self) -> Measurement:
        """Sensor readings at the current state (noise drawn from the seeded generator)."""
        f_true, self._tau_c, (p_W, R_W_ee, _) = self._contact(self.q)
        return self._measurement(f_true, p_W, R_W_ee)

    def _measurement(self, f_true: np.ndarray, p_W: np.ndarray,
                     R_W_ee: np.ndarray) -> Measurement:
        """Return the sensors' readings of the current state, from its true force and tool pose."""
        f_meas = (f_true + self.rng.normal(0.0, self.noise_sigma, 3) if self.noise_sigma
                  else f_true.copy())
        # q, qdot and tau are rebound (never mutated) by step(), so no copies are needed
        f_n = math.sqrt(f_true.dot(f_true))  # |f| (np.linalg.norm's sum); along the normal only
        return Measurement(self.t, self.q, self.qdot, self.tau, p_W, R_W_ee,
                           f_meas, f_true, in_contact(f_n))
