"""Closed-form inverses of the small matrices of the control law's hot path (pure numpy)."""
from __future__ import annotations

import numpy as np

__all__ = ['small_inverse']


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
