"""Small dense linear algebra of the 1 kHz path (pure numpy)."""
from __future__ import annotations

import math

import numpy as np

__all__ = ['all_finite', 'damped_inverse', 'sigma_min_sq', 'sigma_min_sq_bound', 'small_inverse']


def all_finite(x: np.ndarray) -> bool:
    """
    Say whether every element of the 1-D float array ``x`` is finite.

    The sum of its values as Python floats first (0.17 us for 7; NaN and inf make it
    non-finite, and Python's sum overflows without numpy's warning): the per-element test
    (1 us) runs only when that fails, so huge finite values whose sum overflows still pass.
    """
    return math.isfinite(sum(x.tolist())) or bool(np.isfinite(x).all())


def small_inverse(A: np.ndarray) -> np.ndarray:
    """
    Inverse of a square matrix; closed form (adjugate / det) for 2 x 2 and 3 x 3.

    The hot path: the Jacobian of a square arm, ``J M^-1 J^T`` of a redundant one
    (``numpy.linalg.inv`` costs ~8 us on these sizes, the closed forms ~1-2 us).
    """
    if A.shape == (2, 2):
        (a, b), (c, d) = A.tolist()
        det = a * d - b * c
        if det == 0.0:
            raise np.linalg.LinAlgError('singular matrix (a singular pose)')
        return np.array(((d / det, -b / det), (-c / det, a / det)))
    if A.shape == (3, 3):
        (a, b, c), (d, e, f), (g, h, i) = A.tolist()
        adj = ((e * i - f * h, c * h - b * i, b * f - c * e),
               (f * g - d * i, a * i - c * g, c * d - a * f),
               (d * h - e * g, b * g - a * h, a * e - b * d))
        det = a * adj[0][0] + b * adj[1][0] + c * adj[2][0]
        if det == 0.0:
            raise np.linalg.LinAlgError('singular matrix (a singular pose)')
        return np.array(adj) / det
    return np.linalg.inv(A)


def sigma_min_sq(J: np.ndarray) -> float:
    """
    Return the square of the smallest singular value of a square ``J``.

    2 x 2 in closed form, ``2 det^2 / (F + sqrt(F^2 - 4 det^2))`` with ``F = |J|_F^2`` (no
    cancellation near a singularity); otherwise the smallest eigenvalue of ``J J^T``.
    """
    if J.shape == (2, 2):
        (a, b), (c, d) = J.tolist()
        det, F = a * d - b * c, a * a + b * b + c * c + d * d
        return 2.0 * det * det / (F + math.sqrt(max(F * F - 4.0 * det * det, 0.0)) or 1.0)
    return float(np.linalg.eigvalsh(J.dot(J.T))[0])


def sigma_min_sq_bound(J: np.ndarray) -> float:
    r"""
    Return a lower bound of the smallest squared singular value of ``J`` (m x n, m <= n).

    It is :math:`1 / \operatorname{tr}((J J^T)^{-1}) = 1 / \sum_i \sigma_i^{-2}`, within a
    factor m of it (tight near a singularity, where one term dominates the sum). For m = 3 in
    closed form, ``det / (sum of the principal 2 x 2 minors)`` of ``J J^T`` (no
    eigen-decomposition on the 1 kHz path); 0 at a singular J.
    """
    G = J.dot(J.T)
    if G.shape == (3, 3):
        (a, b, c), (_, e, f), (_, _, i) = G.tolist()
        minors = (e * i - f * f) + (a * i - c * c) + (a * e - b * b)
        det = a * (e * i - f * f) - b * (b * i - f * c) + c * (b * f - e * c)
        return max(det, 0.0) / minors if minors > 0.0 else 0.0
    try:
        return 1.0 / float(sum(np.linalg.inv(G).diagonal().tolist()))
    except np.linalg.LinAlgError:
        return 0.0


def damped_inverse(J: np.ndarray, sigma0: float) -> tuple[np.ndarray, bool]:
    r"""
    Return ``J^-1`` of a square ``J``, damped near a singularity, and whether it is damped.

    Damped least squares with a variable damping (Nakamura and Hanafusa, 1986; Chiaverini,
    1997): with :math:`\sigma` the smallest singular value of J and
    :math:`\sigma_0` = ``sigma0``,

    .. math::

        J^\# = J^T (J J^T + \mu^2 I)^{-1}, \qquad
        \mu^2 = \sigma_0^2 - \sigma^2 \ \ (\sigma < \sigma_0), \quad 0 \ \text{otherwise}

    so :math:`J^\# = J^{-1}` away from the singularity, continuous at
    :math:`\sigma = \sigma_0`, and along the singular direction the gain
    :math:`\sigma / (\sigma^2 + \mu^2) = \sigma / \sigma_0^2` falls to 0 instead of
    :math:`1 / \sigma` growing without bound. ``sigma0`` 0: never damped.
    """
    s2 = sigma_min_sq(J)
    mu2 = sigma0 * sigma0 - s2
    if mu2 <= 0.0:
        return small_inverse(J), False
    JJt = J.dot(J.T)
    JJt[np.diag_indices_from(JJt)] += mu2
    return J.T.dot(small_inverse(JJt)), True
