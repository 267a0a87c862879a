"""
Unilateral elastic surface: the environment model of eqs. (12)-(13) of [1].

[1] Jafari et al., "An Adaptive Hybrid Force/Motion Control Design for Robot Manipulators
Interacting in Constrained Motion with Unknown Non-Rigid Environments".
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ['ElasticSurface', 'SurfaceError', 'f_W_from_sensor_wrench', 'sensor_wrench_from_f_W']


class SurfaceError(ValueError):
    """Invalid surface description (non-positive stiffness, bad normal, non-finite point)."""


@dataclass(frozen=True)
class ElasticSurface:
    """
    A frictionless elastic plane that pushes but never pulls.

    Eqs. (12)-(13) of [1]: ``f = k n n^T (x - x0)`` while the tool is inside the surface
    (``n^T (x - x0) > 0``) and ``f = 0`` otherwise. ``f`` is the force the tool exerts on
    the surface; the surface pushes the tool with ``-f``.

    Attributes
    ----------
    k : stiffness k > 0, N/m.
    x0_W : (3,) a point of the undeformed plane, base frame, m.
    n_W : (3,) unit normal pointing into the surface (the direction the tool pushes).

    """

    k: float
    x0_W: np.ndarray
    n_W: np.ndarray

    @classmethod
    def create(cls, k: float, x0_W, n_W) -> 'ElasticSurface':
        """Validate and normalise; raises :class:`SurfaceError` on bad input."""
        x0 = np.asarray(x0_W, dtype=float).reshape(-1)
        n = np.asarray(n_W, dtype=float).reshape(-1)
        if not (np.isfinite(k) and k > 0):
            raise SurfaceError(f'surface stiffness must be finite and > 0, got {k}')
        if x0.shape != (3,) or not np.all(np.isfinite(x0)):
            raise SurfaceError(f'surface point must be 3 finite numbers, got {x0_W}')
        norm = float(np.linalg.norm(n)) if n.shape == (3,) else 0.0
        if not (np.isfinite(norm) and norm > 1e-9):
            raise SurfaceError(f'surface normal must be a non-zero finite 3-vector, got {n_W}')
        return cls(float(k), x0, n / norm)

    def penetration(self, p_W: np.ndarray) -> float:
        """Signed depth ``n^T (x - x0)``, m (positive inside the surface)."""
        return float(self.n_W @ (p_W - self.x0_W))

    def force(self, p_W: np.ndarray) -> np.ndarray:
        """Contact force the tool exerts on the surface, base frame, eqs. (12)-(13)."""
        depth = self.penetration(p_W)
        return (self.k * depth) * self.n_W if depth > 0.0 else np.zeros(3)


def sensor_wrench_from_f_W(R_W_ee: np.ndarray, f_W: np.ndarray) -> np.ndarray:
    """
    Force the environment exerts on the tool, in the end-effector frame: ``-R^T f_W``.

    This is what a wrist force/torque sensor reports (ROS convention of
    force_torque_sensor_broadcaster: the external wrench acting on the sensor frame).
    """
    return -(R_W_ee.T @ f_W)


def f_W_from_sensor_wrench(R_W_frame: np.ndarray, F_frame: np.ndarray) -> np.ndarray:
    """Inverse of :func:`sensor_wrench_from_f_W`: the force the tool exerts, base frame."""
    return -(R_W_frame @ F_frame)
