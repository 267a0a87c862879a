"""
Unilateral elastic surfaces: the environment model of eqs. (12)-(13) of [1], and curved ones.

:class:`ElasticSurface` is the paper's plane. :class:`CylinderSurface` and
:class:`SphereSurface` are convex workpieces pressed from outside, with the same spring along
the *local* normal: ``f = k depth n(x)``. All have ``k``, ``x0_W`` (a point of the undeformed
surface), ``n_W`` (the normal into the surface at ``x0_W``), ``shape``, ``penetration(p)``,
``force(p)`` and ``normal_at(p)``; :func:`make_surface` builds any of them from the sim's
parameters and raises :class:`SurfaceError` with the reason for a bad one.

[1] Jafari et al., "An Adaptive Hybrid Force/Motion Control Design for Robot Manipulators
Interacting in Constrained Motion with Unknown Non-Rigid Environments".
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, ClassVar, Sequence, Union

import numpy as np

__all__ = ['AXIS_TOLERANCE_DEG', 'CylinderSurface', 'ElasticSurface', 'SURFACE_SHAPES',
           'SphereSurface', 'Surface', 'SurfaceError', 'default_axis', 'f_W_from_sensor_wrench',
           'make_surface', 'sensor_wrench_from_f_W']

SURFACE_SHAPES = ('plane', 'cylinder', 'sphere')
AXIS_TOLERANCE_DEG = 1.0  # how far a cylinder's axis may be off the tangent plane (projected)


class SurfaceError(ValueError):
    """Invalid surface description (bad stiffness, normal, point, shape, radius or axis)."""


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
    shape: ClassVar[str] = 'plane'

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

    def normal_at(self, p_W: np.ndarray) -> np.ndarray:
        """Return the unit normal into the surface nearest ``p_W``: ``n_W`` everywhere."""
        return self.n_W


@dataclass(frozen=True)
class _RoundSurface:
    """
    A convex round workpiece of radius R pressed from outside: a spring along the local normal.

    The surface passes through ``x0_W`` with its normal into the surface there equal to ``n_W``,
    so its centre (a point for the sphere, a point of the axis for the cylinder) lies on the far
    side, ``c_W = x0_W + R n_W``. With ``rho(p)`` the vector from the centre (or the axis) to
    ``p``, perpendicular to the axis for a cylinder::

        depth(p) = R - |rho(p)|,    n(p) = -rho(p) / |rho(p)|,    f = k depth n(p) if depth > 0

    ``n(p)`` points into the surface (towards the centre), as the plane's ``n_W`` does; at the
    centre itself (deeper than any real contact) it is ``n_W``.
    """

    k: float
    x0_W: np.ndarray
    n_W: np.ndarray
    radius: float
    c_W: np.ndarray

    def _rho(self, p_W: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def penetration(self, p_W: np.ndarray) -> float:
        """Signed depth ``R - |rho|``, m (positive inside the surface)."""
        rho = self._rho(p_W)
        return self.radius - math.sqrt(float(rho @ rho))

    def normal_at(self, p_W: np.ndarray) -> np.ndarray:
        """Return the unit normal into the surface at the point nearest ``p_W``, base frame."""
        rho = self._rho(p_W)
        r = math.sqrt(float(rho @ rho))
        return self.n_W if not r > 1e-12 * self.radius else rho * (-1.0 / r)

    def force(self, p_W: np.ndarray) -> np.ndarray:
        """Contact force the tool exerts on the surface, base frame: ``k depth n(p)``."""
        rho = self._rho(p_W)
        r = math.sqrt(float(rho @ rho))
        depth = self.radius - r
        if not depth > 0.0:
            return np.zeros(3)
        n = self.n_W if not r > 1e-12 * self.radius else rho * (-1.0 / r)
        return (self.k * depth) * n


@dataclass(frozen=True)
class SphereSurface(_RoundSurface):
    """A sphere of radius R through ``x0_W``, centre ``x0_W + R n_W`` (see the base class)."""

    shape: ClassVar[str] = 'sphere'

    def _rho(self, p_W: np.ndarray) -> np.ndarray:
        return p_W - self.c_W


@dataclass(frozen=True)
class CylinderSurface(_RoundSurface):
    """
    A cylinder of radius R along ``axis_W`` (unit, perpendicular to ``n_W``) through ``x0_W``.

    Infinitely long on the paper's physics; its axis passes through ``x0_W + R n_W``.
    """

    axis_W: np.ndarray
    shape: ClassVar[str] = 'cylinder'

    def _rho(self, p_W: np.ndarray) -> np.ndarray:
        d = p_W - self.c_W
        return d - float(d @ self.axis_W) * self.axis_W


Surface = Union[ElasticSurface, SphereSurface, CylinderSurface]


def default_axis(n_W: np.ndarray) -> np.ndarray:
    """Return the base axis (z, x, then y on a tie) most perpendicular to the unit ``n_W``."""
    candidates = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    return candidates[int(np.argmin(np.abs(candidates @ n_W)))]


def _axis(axis_W: Any, n_W: np.ndarray) -> np.ndarray:
    """Validate a cylinder axis; return it unit and exactly perpendicular to ``n_W``."""
    a = np.asarray(axis_W if axis_W is not None and len(axis_W) else default_axis(n_W),
                   dtype=float).reshape(-1)
    norm = float(np.linalg.norm(a)) if a.shape == (3,) else 0.0
    if not (math.isfinite(norm) and norm > 1e-9):
        raise SurfaceError(f'surface axis must be a non-zero finite 3-vector, got {axis_W}')
    a = a / norm
    off = math.degrees(math.asin(min(1.0, abs(float(a @ n_W)))))
    if off > AXIS_TOLERANCE_DEG:
        raise SurfaceError(f'surface axis {a.round(4).tolist()} must be perpendicular to the '
                           f'surface normal {n_W.round(4).tolist()} (it is {off:.2f} deg off the '
                           f'tangent plane; at most {AXIS_TOLERANCE_DEG:g} deg)')
    a = a - float(a @ n_W) * n_W
    return a / float(np.linalg.norm(a))


def make_surface(shape: str, k: float, x0_W: Any, n_W: Any, radius: float = 0.5,
                 axis_W: Sequence[float] | None = None) -> Surface:
    """
    Build and validate a surface of ``shape`` (one of :data:`SURFACE_SHAPES`).

    ``x0_W`` is a point of the undeformed surface where its normal into the surface is
    ``n_W`` (any length): a plane's point and normal, or where a cylinder or sphere of
    ``radius`` (m) is touched, its centre on the far side (``x0_W + radius n_W``). A cylinder's
    axis ``axis_W`` (base frame; None or empty: :func:`default_axis`) must lie within
    :data:`AXIS_TOLERANCE_DEG` of the tangent plane and is projected onto it. Raises
    :class:`SurfaceError` naming what is wrong.
    """
    plane = ElasticSurface.create(k, x0_W, n_W)
    if shape == 'plane':
        return plane
    if shape not in SURFACE_SHAPES:
        raise SurfaceError(f'surface shape must be one of {list(SURFACE_SHAPES)}, got {shape!r}')
    if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not (
            math.isfinite(radius) and radius > 0.0):
        raise SurfaceError(f'surface radius must be finite and > 0, got {radius!r}')
    R, x0, n = float(radius), plane.x0_W, plane.n_W
    if shape == 'sphere':
        return SphereSurface(plane.k, x0, n, R, x0 + R * n)
    return CylinderSurface(plane.k, x0, n, R, x0 + R * n, _axis(axis_W, n))


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
