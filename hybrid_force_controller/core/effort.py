"""
What the runtime does with efforts: the limits every command obeys, and the safe hold.

Pure numpy + pinocchio (through :class:`~.robot_model.RobotModel`).
"""
from __future__ import annotations

import numpy as np

from .robot_model import RobotModel

__all__ = ['EffortLimiter', 'SafeHold']


class EffortLimiter:
    """
    Clamp to per-joint effort limits and, optionally, a per-tick rate limit.

    Every command the runtime publishes goes through :meth:`__call__`; :meth:`reset`
    forgets the last command (a restart does not rate-limit against a stale one).
    """

    def __init__(self, limits: np.ndarray, max_rate: float = 0.0) -> None:
        self.configure(limits, max_rate)
        self._last: np.ndarray | None = None

    def configure(self, limits: np.ndarray, max_rate: float) -> None:
        """Install new limits (a parameter set); the last command is kept for the rate limit."""
        self.limits, self.max_rate = np.asarray(limits, dtype=float), float(max_rate)
        self._lower = -self.limits

    def reset(self) -> None:
        self._last = None

    def __call__(self, tau: np.ndarray) -> tuple[np.ndarray, bool]:
        """Limit ``tau``; return the limited effort and whether a limit was active."""
        out = tau
        if self.max_rate > 0.0 and self._last is not None:
            out = np.minimum(np.maximum(out, self._last - self.max_rate),
                             self._last + self.max_rate)
        out = np.minimum(np.maximum(out, self._lower), self.limits)
        self._last = out
        return out, out.tolist() != tau.tolist()


class SafeHold:
    """
    Safe-mode effort: hold the arm where it is, adaptation and force loop frozen.

    ``tau = g_hat(q) + J^T f_hold`` (the adapted gravity torque plus the contact force
    latched when safe mode began, so the arm keeps its place against the surface) and, only
    while the joint velocity is fresh, ``- k_d J^T J qdot`` (and ``- k_null qdot`` on
    redundant arms): a stale velocity damped would act as a constant push. Adding the live
    force instead of the latched one would cancel the surface's reaction (with a stale q: a
    positive feedback).
    """

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        self._zero = np.zeros(model.n)
        self.f_hold = np.zeros(model.m)

    def latch(self, f_W: np.ndarray) -> None:
        """Hold the force ``f_W`` (base frame) from now on."""
        self.f_hold = np.array(f_W[self.model.task_index], dtype=float)

    def effort(self, q: np.ndarray, qdot: np.ndarray, theta_hat: np.ndarray, k_d: float,
               k_null: float, fresh_velocity: bool) -> tuple[np.ndarray, np.ndarray]:
        """Return the hold effort and the end-effector position (base frame) at ``q``."""
        model, z = self.model, self._zero
        kin = model.kinematics(q, qdot)
        Y_g, tau_0 = model.regressor_affine(q, z, z, z)
        tau = Y_g @ theta_hat + kin.J_ee.T @ self.f_hold
        if tau_0 is not None:
            tau += tau_0
        if fresh_velocity:
            tau -= k_d * (kin.J_ee.T @ kin.xdot)
            if model.redundant:
                tau -= k_null * qdot
        if not np.all(np.isfinite(tau)):
            tau = np.zeros(model.n)
        return tau, kin.p_W
