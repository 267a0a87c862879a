"""
The adaptation law, eq. (26) of [1], with its projection, saturation and dead zone (pure numpy).

``theta_hat_dot = -Gamma^-1 Y_x^T (k_a e)`` (control_law.py explains the units ``k_a e``): the
step is integrated over the time the newest state covers, then projected onto the box
``[theta_min, theta_max]``; e enters scaled by :func:`adaptation_weight`.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['adapt_theta', 'adaptation_weight']


def adapt_theta(theta_hat: np.ndarray, Gamma_inv: np.ndarray, Y_x: np.ndarray, e: np.ndarray,
                dt: float, theta_min: np.ndarray, theta_max: np.ndarray) -> np.ndarray:
    """
    Adaptation law, eq. (26) of [1], with projection onto a box.

    ``theta_hat_dot = -Gamma^-1 Y_x^T e``, integrated over ``dt`` (explicit Euler), then
    clipped to ``[theta_min, theta_max]``. With a diagonal Gamma the clip is the
    orthogonal projection in the Gamma metric, so the Lyapunov term
    ``theta_tilde^T Gamma theta_tilde`` does not grow (the true theta lies in the box).
    """
    return np.minimum(np.maximum(theta_hat - dt * Gamma_inv.dot(e.dot(Y_x)), theta_min), theta_max)


def adaptation_weight(e: np.ndarray, error_limit: float, dead_zone: float) -> float:
    """
    Scale of e in (26): the saturation to ``adapt_error_limit`` and the dead zone.

    ``w = min(1, e_lim / |e|) max(0, 1 - d / |e|)``: a transient (``|e| > e_lim``) adapts
    in the direction of e with a bounded size (control_law.py), an error below the dead
    zone d (sensor noise) does not adapt at all, and w is continuous in e.
    """
    e_norm = math.sqrt(e.dot(e))
    if e_norm <= dead_zone:
        return 0.0
    w = 1.0 if e_norm <= error_limit else error_limit / e_norm
    return w * (1.0 - dead_zone / e_norm) if dead_zone > 0.0 else w
