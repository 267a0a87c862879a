"""
What the runtime does with efforts: the limits every command obeys, and the safe hold.

Pure numpy + pinocchio (through :class:`~.robot_model.RobotModel`).
"""
from __future__ import annotations

import math

from typing import Sequence

import numpy as np

from ..law.bumpless import RestartBlend
from ..model.robot_model import RobotModel

__all__ = ['CommandStage', 'EffortLimiter', 'SafeHold']


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


class CommandStage:
    """
    The effort's way out: the limits, the bumpless blend after a restart, the command order.

    :meth:`__call__` limits an effort (model order), blends it from the one the hardware held
    after a restart (law/bumpless.py), keeps it as :attr:`tau_last` and returns it in the order
    of ``joints`` (a fresh array: none is ever mutated).
    """

    def __init__(self, limits: np.ndarray) -> None:
        self.limiter = EffortLimiter(limits)
        self.blend = RestartBlend()
        self.tau_last: np.ndarray | None = None  # the last effort out (model order)
        self.order: list[int] | None = None

    def configure(self, model_joints: Sequence[str], joints: Sequence[str], limits: np.ndarray,
                  max_rate: float) -> None:
        """Install the limits and the command order (None: the model's)."""
        order = [list(model_joints).index(j) for j in joints]
        self.order = None if order == list(range(len(order))) else order
        self.limiter.configure(limits, max_rate)

    def restart(self, blend: bool) -> None:
        """Forget the rate limit's last effort; ``blend``: blend from the held one (bumpless)."""
        self.limiter.reset()
        if blend:
            self.blend.arm(self.tau_last)

    def __call__(self, tau: np.ndarray, t: float) -> tuple[np.ndarray, bool]:
        """Return the effort to command at ``t`` (command order) and whether a limit acted."""
        tau, saturated = self.limiter(tau)
        tau = self.tau_last = self.blend(tau, t)
        return (tau if self.order is None else tau[self.order]), saturated


class SafeHold:
    r"""
    Safe-mode effort: stop the tool smoothly, then hold it there; adaptation and force loop frozen.

    At entry (:meth:`latch`, time :math:`t_0`) the hold takes the tool's task position
    :math:`x_0` and velocity :math:`v_0` and a reference that brakes to rest, critically
    damped with the time constant :math:`T` = ``T_STOP`` (:math:`s = (t - t_0)/T`):

    .. math::

        x_h = x_0 + v_0 T \bigl(2 - (2 + s) e^{-s}\bigr), \qquad \dot x_h = v_0 (1 + s) e^{-s}

    so the deceleration starts at zero, peaks at :math:`v_0 / (e T)` and the tool travels
    :math:`2 v_0 T`. Braking excites the normal force through the arm's inertia: offline, from
    the sine's 0.1 m/s, the force rose 0.18 N with T = 0.05 s, 0.085 N with 0.1 s and 0.035 N
    with 0.2 s (test_runtime.py).

    The effort is the adapted gravity torque, the contact force latched at entry and the law's
    own task impedance (:math:`K_D` of eq. 5, stiffness :math:`K_D \lambda_1` of eq. 11)
    around that reference, plus a constant offset:

    .. math::

        \tau = \hat g(q) + J^T \bigl(f_{hold} + K_D (\dot x_h - \dot x)
               + K_D \lambda_1 (x_h - x)\bigr) + \tau_{offset}

    (and :math:`- k_{null} \dot q` on redundant arms). The impedance terms need the joint
    state: while it is stale they are left out (a stale velocity damped, or a stale position
    held, would act as a constant push). Adding the live force instead of the latched one would
    cancel the surface's reaction (with a stale q: a positive feedback).

    A hold that began on a stale joint state (a stall: the first tick after it sees the
    state from before it) takes its reference's start from the first fresh state instead:
    held to the stale position, the impedance pulled the arm back to where it was before the
    stall, at the effort limits (real time: 4.5 cm after a 300 ms freeze of the controller,
    the paper's arm flung off the surface or pressed into it at 426-512 N).

    :math:`\tau_{offset}` is the last effort out minus :math:`\hat g + J^T f_{hold}` at entry:
    what the law was adding beyond the model (the force loop's integral, the estimate's
    residual, the reference's acceleration), held as an effort controller holds its last
    command. With it, and with the reference starting at the tool's own position and velocity,
    the effort is continuous at entry. The hold used to damp the velocity to zero at once
    (:math:`-K_D \dot x`) without the offset: the effort stepped at entry by 6 N along the
    tangent (the sine's 0.1 m/s) and by the law's residual. After a frozen force sensor the
    normal force then rose 0.3 to 0.5 N in some runs, and in others the tool left the surface
    and stayed off for the rest of the hold (the force came back 1.8 to 2.1 s after the fault
    instead of at once).
    """

    T_STOP = 0.1  # s: the hold's braking time (0.1 m/s stops within 2 v0 T = 2 cm)

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        self._zero = np.zeros(model.n)
        self.f_hold = np.zeros(model.m)
        self.tau_offset = np.zeros(model.n)
        self.t0, self.x0, self.v0 = 0.0, np.zeros(model.m), np.zeros(model.m)
        self.motion_fresh = True  # x0, v0 come from a fresh joint state

    def latch(self, t: float, f_W: np.ndarray, q: np.ndarray, qdot: np.ndarray,
              theta_hat: np.ndarray, tau_last: np.ndarray | None,
              fresh_state: bool = True) -> None:
        """
        Begin a hold at time ``t``: latch the force ``f_W`` (base frame) and the tool's motion.

        ``q``, ``qdot`` are a validated (finite) joint state; ``tau_last`` is the last effort
        out (None, or not finite: no offset). Without ``fresh_state`` the motion is taken
        again from the first fresh state (:meth:`effort`).
        """
        self.f_hold = np.array(f_W[self.model.task_index], dtype=float)
        tau, kin = self._static(q, qdot, theta_hat)
        self.t0, self.x0, self.v0 = t, kin.x.copy(), kin.xdot.copy()
        self.motion_fresh = fresh_state
        offset = self._zero if tau_last is None else tau_last - tau
        self.tau_offset = offset if np.all(np.isfinite(offset)) else self._zero

    def reference(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """Return the hold's task position and velocity ``(x_h, xdot_h)`` at time ``t``."""
        T = self.T_STOP
        s = max(t - self.t0, 0.0) / T
        decay = math.exp(-s)
        return self.x0 + self.v0 * (T * (2.0 - (2.0 + s) * decay)), self.v0 * ((1.0 + s) * decay)

    def effort(self, t: float, q: np.ndarray, qdot: np.ndarray, theta_hat: np.ndarray,
               k_d: float, lambda1: float, k_null: float,
               fresh_state: bool) -> tuple[np.ndarray, np.ndarray]:
        """Return the hold effort at time ``t`` and the end-effector position (base frame)."""
        tau, kin = self._static(q, qdot, theta_hat)
        tau += self.tau_offset
        if fresh_state:
            if not self.motion_fresh:  # the hold began on a stale state: start from this one
                self.t0, self.x0, self.v0 = t, kin.x.copy(), kin.xdot.copy()
                self.motion_fresh = True
            x_h, xdot_h = self.reference(t)
            tau += kin.J_ee.T @ (k_d * (xdot_h - kin.xdot) + (k_d * lambda1) * (x_h - kin.x))
            if self.model.redundant:
                tau -= k_null * qdot
        if not np.all(np.isfinite(tau)):
            tau = np.zeros(self.model.n)
        return tau, kin.p_W

    def _static(self, q: np.ndarray, qdot: np.ndarray, theta_hat: np.ndarray) -> tuple:
        """Return ``g_hat(q) + J^T f_hold`` and the kinematics at (q, qdot)."""
        model, z = self.model, self._zero
        kin = model.kinematics(q, qdot)
        Y_g, tau_0 = model.regressor_affine(q, z, z, z)
        tau = Y_g @ theta_hat + kin.J_ee.T @ self.f_hold
        if tau_0 is not None:
            tau += tau_0
        return tau, kin
