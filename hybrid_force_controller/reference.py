"""Desired motion x_d(t) with its derivatives (section V of [1]), pure numpy."""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

__all__ = ['Reference', 'SineReference', 'blend_start']


class Reference(NamedTuple):
    """Desired position, velocity and acceleration in the base frame (each (3,))."""

    x_d_W: np.ndarray
    xdot_d_W: np.ndarray
    xddot_d_W: np.ndarray


@dataclass(frozen=True)
class SineReference:
    """``x_d(t) = center + amplitude * sin(omega t)``; the paper uses 1 + 0.1 sin t along x."""

    center_W: np.ndarray
    amplitude_W: np.ndarray
    omega: float

    def __call__(self, t: float) -> Reference:
        """Evaluate at time ``t`` (s)."""
        s, c = np.sin(self.omega * t), np.cos(self.omega * t)
        w = self.omega
        return Reference(self.center_W + self.amplitude_W * s,
                         self.amplitude_W * (w * c), self.amplitude_W * (-w * w * s))


def blend_start(ref: Reference, offset_W: np.ndarray, t: float, t_blend: float) -> Reference:
    """Start the reference where the arm is and blend into ``ref`` over ``t_blend`` s.

    ``x_ref = x_d + b(t) offset`` with the quintic ``b = 1 - (10 s^3 - 15 s^4 + 6 s^5)``,
    ``s = t / t_blend``, so position, velocity and acceleration stay continuous at both
    ends. ``offset_W = x(0) - x_d(0)``. The paper's scenario starts 0.21 m away from
    x_d(0); without the blend the initial velocity demand is lambda1 * 0.21 = 8.4 m/s.
    """
    if t_blend <= 0.0 or t >= t_blend:
        return ref
    s = t / t_blend
    b = 1.0 - (10 * s**3 - 15 * s**4 + 6 * s**5)
    db = -(30 * s**2 - 60 * s**3 + 30 * s**4) / t_blend
    ddb = -(60 * s - 180 * s**2 + 120 * s**3) / t_blend**2
    return Reference(ref.x_d_W + b * offset_W, ref.xdot_d_W + db * offset_W,
                     ref.xddot_d_W + ddb * offset_W)
