r"""
The task's inverse for a redundant arm, damped near a singularity, and the 6-D task's damping.

Used by the law's tick (control_law.py), at 1 kHz. Pure numpy; no state.

For redundant arms (joints > task dimension) eqs. (35)-(37) generalise with the dynamically
consistent inverse ``Jbar = M^-1 J^T (J M^-1 J^T)^-1`` in place of J^-1:
``qdot_r = Jbar r``, ``qddot_r = Jbar (rdot - Jdot qdot_r)`` (the derivative of Jbar is
neglected), and ``N = I - Jbar J`` projects onto motions that leave the end effector still;
``-k_null N^T N s`` damps them. M is the URDF inertia.

Near a singularity it is damped as linalg.damped_inverse damps a square J, in the metric of
M^-1 (:math:`\bar m^{-1} = \operatorname{tr} M^{-1} / n`; for ``M = m I`` exactly damped least
squares): with :math:`\tilde\sigma^2` a lower bound of J's smallest squared singular value
below ``sigma0``,

.. math::

    \bar J = M^{-1} J^T (J M^{-1} J^T + \mu^2 \bar m^{-1} I)^{-1}, \qquad
    \mu^2 = \sigma_0^2 - \tilde\sigma^2

and theta_hat holds (the caller's ``damped``), :math:`\tilde\sigma^2` from
linalg.sigma_min_sq_bound. (Read off ``(J M^-1 J^T)^-1``, which the inverse needs anyway, the
bound would save a 6 x 6 inverse per tick, but in M's metric it damps the Panda at ordinary
poses: its wrist's small inertias weigh the metric. Tried and measured: not kept.)
"""
from __future__ import annotations

import numpy as np

from ..model.linalg import sigma_min_sq_bound, small_inverse

__all__ = ['angular_damping', 'redundant_inverse']


def redundant_inverse(M_inv: np.ndarray, J: np.ndarray, sigma0: float,
                      eye_n: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """
    Return ``Jbar``, ``N = I - Jbar J`` and whether Jbar is damped (the module's formulas).

    ``M_inv`` the inverse of the joint-space inertia, ``J`` the task Jacobian (m x n, m < n),
    ``sigma0`` the damping's threshold (0: never damped), ``eye_n`` the n x n identity.
    """
    JM = J.dot(M_inv)
    A = JM.dot(J.T)
    mu2 = sigma0 * sigma0 - sigma_min_sq_bound(J) if sigma0 > 0.0 else 0.0
    if mu2 > 0.0:
        A[np.diag_indices_from(A)] += mu2 * sum(M_inv.diagonal().tolist()) / len(M_inv)
    J_pinv = JM.T.dot(small_inverse(A))
    return J_pinv, eye_n - J_pinv.dot(J), mu2 > 0.0


def angular_damping(e_w: np.ndarray, a_W: np.ndarray, k_w: tuple[float, float]) -> np.ndarray:
    """
    Return ``K_w e_w = k_t e_w + (k_s - k_t) (a . e_w) a``: k_t across a, k_s about it.

    ``K_w = k_t (I - a a^T) + k_s a a^T`` with ``a`` the tool axis (unit, W) and
    ``(k_t, k_s) = k_w`` (N m s/rad): the tilt and the spin damped apart (docs/design.md).
    """
    k_t, k_s = k_w
    return k_t * e_w + ((k_s - k_t) * float(a_W.dot(e_w))) * a_W
