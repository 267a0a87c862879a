"""The adaptive hybrid force/motion control law of [1], eqs. (5)/(6), (8), (11) and (26).

[1] Jafari et al., "An Adaptive Hybrid Force/Motion Control Design for Robot Manipulators
Interacting in Constrained Motion with Unknown Non-Rigid Environments".

Pure numpy + pinocchio (through :class:`RobotModel`). Time is an argument: the caller
passes ``dt``; nothing here reads a clock.

Well-posed eq. (11). The literal error vector adds force-rate terms (N/s) to velocity
terms (m/s). Here the S-part is scaled by a compliance ``c = 1/k_s`` (m/N), the force rate
is the model-based estimate ``fdot_hat = k_s n^T xdot`` (no differentiated force), and
lambda2 is read in m/(N s^2), the units in which eqs. (21) and (29) are consistent:

    e = (I - S)(dxdot + lambda1 dx) + n (c dfdot_hat + c lambda1 df_n + lambda2 h)

so with ``r = xdot - e`` (eq. 8) the normal part of r holds no velocity and ``rdot``
needs no acceleration:

    r    = (I - S)(xdot_d - lambda1 dx) + n (c fdot_d - c lambda1 df_n - lambda2 h)
    rdot = (I - S)(xddot_d - lambda1 dxdot) - n (lambda1 (n^T xdot - c fdot_d) + lambda2 df_n)

Along n this is a PI force loop on a velocity reference. With e = 0 its closed loop is
``hddot + (k/k_s) lambda1 hdot + lambda2 k h = 0``; eq. (29), ``lambda1^2 > 2 lambda2
k_max``, is then dimensionally consistent and (with k_s = k_max) says this loop is damped
better than 1/sqrt(2) at the stiffest surface.

Adaptation units. Eq. (26) is applied to e expressed in the paper's force-rate units,
``k_s e`` (N/s), i.e. ``theta_hat_dot = -Gamma^-1 Y_x^T (k_s e)``. That is (26) in SI units
with ``Gamma/k_s``, so the Lyapunov function (27) keeps its form; with the paper's
Gamma = 70 I it makes the estimates converge in about a second instead of minutes.
"""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from .params import ControllerParams
from .reference import Reference
from .robot_model import RobotModel

__all__ = ['ControlError', 'ControlOutput', 'HybridForceController', 'adapt_theta']


class ControlError(ValueError):
    """The control law met non-finite or inconsistent input it cannot act on."""


class ControlOutput(NamedTuple):
    """One tick's result: the clamped effort, e (task coordinates, ``model.task_axes``),
    theta_hat after the update, the force integral h and whether a limit was active."""

    tau: np.ndarray
    e: np.ndarray
    theta_hat: np.ndarray
    h: float
    saturated: bool


def in_contact(f_n: float, f_d: float) -> bool:
    """Contact test on the measured normal force: ``f_n > max(0.05 N, 0.1 f_d)``."""
    return f_n > max(0.05, 0.1 * f_d)


def small_inverse(A: np.ndarray) -> np.ndarray:
    """Inverse of a square matrix; closed form for 2 x 2 (the hot path of planar arms)."""
    if A.shape == (2, 2):
        a, b, c, d = A.ravel().tolist()
        det = a * d - b * c
        if det == 0.0:
            raise np.linalg.LinAlgError('singular Jacobian')
        return np.array(((d / det, -b / det), (-c / det, a / det)))
    return np.linalg.inv(A)


def adapt_theta(theta_hat: np.ndarray, Gamma_inv: np.ndarray, Y_x: np.ndarray, e: np.ndarray,
                dt: float, theta_min: np.ndarray, theta_max: np.ndarray) -> np.ndarray:
    """Adaptation law, eq. (26) of [1], with projection onto a box.

    ``theta_hat_dot = -Gamma^-1 Y_x^T e``, integrated over ``dt`` (explicit Euler), then
    clipped to ``[theta_min, theta_max]``. With a diagonal Gamma the clip is the
    orthogonal projection in the Gamma metric, so the Lyapunov term
    ``theta_tilde^T Gamma theta_tilde`` does not grow (the true theta lies in the box).
    """
    return np.minimum(np.maximum(theta_hat - dt * (Gamma_inv @ (Y_x.T @ e)), theta_min), theta_max)


class HybridForceController:
    """Adaptive hybrid force/motion controller for one arm model.

    ``set_params`` swaps the gains atomically (the next ``step`` uses the new set);
    ``step`` computes one command from the latest state.
    """

    def __init__(self, model: RobotModel, params: ControllerParams) -> None:
        self.model = model
        self._project = model.parameter_set.project
        self._eye_n = np.eye(model.n)
        self.set_params(params)
        self.reset()

    def set_params(self, params: ControllerParams) -> None:
        """Install a validated parameter set; derived matrices are computed here, once."""
        ax = list(self.model.task_axes)
        n = params.n[ax]
        if hasattr(self, 'params') and not np.array_equal(params.n, self.params.n):
            self.h = 0.0  # the force integral belongs to the old normal
        P_t = np.eye(len(ax)) - np.outer(n, n)
        self._derived = (params, n, self._linear_part(P_t, n, params.lambda1),
                         np.linalg.inv(params.Gamma), 1.0 / params.k_s)
        self.params = params

    def _linear_part(self, P_t: np.ndarray, n: np.ndarray, l1: float) -> np.ndarray:
        """G with ``G z = [r; rdot]`` minus their force terms, ``z = (x, xdot, x_d, xdot_d,
        xddot_d)`` (x, xdot in task coordinates, the reference 3-D): one product per tick."""
        m = len(n)
        A = np.eye(3)[list(self.model.task_axes)]  # base frame -> task coordinates
        Z = np.zeros((m, m))
        r_row = np.hstack([-l1 * P_t, Z, l1 * P_t @ A, P_t @ A, np.zeros((m, 3))])
        rdot_row = np.hstack([Z, -l1 * P_t - l1 * np.outer(n, n), np.zeros((m, 3)),
                              l1 * P_t @ A, P_t @ A])
        return np.vstack([r_row, rdot_row])

    def reset(self, theta_hat: np.ndarray | None = None) -> None:
        """Restart the adaptation (``theta_hat0`` by default) and the force integral."""
        p = self.params
        self.theta_hat = (p.theta_hat0 if theta_hat is None else np.asarray(theta_hat)).copy()
        self.h = 0.0
        self.tau_prev: np.ndarray | None = None
        self.last_kin = None  # kinematics of the last step (for the caller's outputs)

    def reference_velocity(self, kin, ref: Reference, f: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
        """r and rdot from eqs. (8) and (11) (scaled form, module docstring); also e, df_n."""
        p, n, G, _, c = self._derived
        m = len(n)
        df_n = float(n @ f) - p.f_d
        l1, l2 = p.lambda1, p.lambda2
        lin = G @ np.concatenate((kin.x, kin.xdot, ref.x_d_W, ref.xdot_d_W, ref.xddot_d_W))
        r = lin[:m] - (c * l1 * df_n + l2 * self.h) * n
        rdot = lin[m:] - (l2 * df_n) * n
        return r, rdot, kin.xdot - r, df_n

    def step(self, q: np.ndarray, qdot: np.ndarray, f_W: np.ndarray, ref: Reference,
             dt: float) -> ControlOutput:
        """One control tick: eqs. (5)/(6) with (8), (11) and the adaptation (26).

        Parameters
        ----------
        q, qdot : joint positions and velocities, in ``model.joint_names`` order.
        f_W : (3,) force the tool exerts on the surface, base frame, N (filtered).
        ref : desired motion at this tick.
        dt : time since the previous tick, s (> 0).

        Returns ``tau = J^T u`` with ``u = Y_x theta_hat - K_D e + f`` clamped to the
        effort limits (and the per-tick rate limit when set).
        """
        if not (dt > 0.0 and math.isfinite(dt)):
            raise ControlError(f'dt must be finite and > 0, got {dt}')
        p, n, _, Gamma_inv, _ = self._derived
        model = self.model
        kin = self.last_kin = model.kinematics(q, qdot)
        f = f_W[model.task_index]
        r, rdot, e, df_n = self.reference_velocity(kin, ref, f)
        J_pinv, N = (self._pinv(q, kin.J_ee) if model.redundant
                     else (small_inverse(kin.J_ee), None))
        qdot_r = J_pinv @ r
        qddot_r = J_pinv @ (rdot - kin.Jdot_ee @ qdot_r)
        Y_q, tau_0 = model.regressor_affine(q, qdot, qdot_r, qddot_r)
        s = qdot - qdot_r  # = J^-1 e for a square J
        tau = Y_q @ self.theta_hat + kin.J_ee.T @ (f - p.k_d * e)
        if tau_0 is not None:
            tau += tau_0
        if N is not None:  # null-space posture damping
            tau -= p.k_null * (N.T @ (N @ s))
        if not math.isfinite(tau.sum()):
            raise ControlError('control law produced a non-finite effort')
        tau_out = self.limit(tau)
        # eq. (26) in joint space: Y_x^T e = Y_q^T J^-1 e = Y_q^T s (square J)
        self.theta_hat = adapt_theta(self.theta_hat, Gamma_inv, Y_q, p.k_s * s, dt,
                                     p.theta_min, p.theta_max)
        if self._project is not None:
            self.theta_hat = self._project(self.theta_hat)
        if in_contact(df_n + p.f_d, p.f_d):  # anti-windup: h frozen while out of contact
            self.h = min(max(self.h + df_n * dt, -p.integral_limit), p.integral_limit)
        else:  # ... and never holding a retreat (h > 0 after a spike or a hard re-contact)
            self.h = min(self.h, 0.0)
        return ControlOutput(tau_out, e, self.theta_hat,
                             self.h, bool((tau_out != tau).any()))

    def _pinv(self, q: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Dynamically consistent inverse ``Jbar = M^-1 J^T (J M^-1 J^T)^-1`` and ``N``.

        For redundant arms (joints > task dimension) eqs. (35)-(37) generalise with Jbar in
        place of J^-1: ``qdot_r = Jbar r``, ``qddot_r = Jbar (rdot - Jdot qdot_r)`` (the
        derivative of Jbar is neglected), and ``N = I - Jbar J`` projects onto motions that
        leave the end effector still; ``-k_null N^T N s`` damps them. M is the URDF inertia.
        """
        M_inv = self.model.inertia_inverse(q)
        JM = J @ M_inv
        J_pinv = JM.T @ np.linalg.inv(JM @ J.T)
        return J_pinv, self._eye_n - J_pinv @ J

    def limit(self, tau: np.ndarray) -> np.ndarray:
        """Clamp to the per-joint effort limits and the optional per-tick rate limit."""
        p = self.params
        if p.max_effort_rate > 0.0 and self.tau_prev is not None:
            tau = np.minimum(np.maximum(tau, self.tau_prev - p.max_effort_rate),
                             self.tau_prev + p.max_effort_rate)
        tau = np.minimum(np.maximum(tau, -p.effort_limits), p.effort_limits)
        self.tau_prev = tau
        return tau
