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


def blend_start(ref: Reference, offset_W: np.ndarray, t: float, t_blend: float,
                offset_vel_W: np.ndarray | None = None) -> Reference:
    """Start the reference where the arm is (and as fast) and blend into ``ref``.

    ``x_ref = x_d + H0(s) dp + t_blend H1(s) dv`` with ``s = t / t_blend`` and the quintic
    Hermite basis ``H0 = 1 - 10 s^3 + 15 s^4 - 6 s^5``, ``H1 = s - 6 s^3 + 8 s^4 - 3 s^5``:
    at t = 0 the reference equals the arm's position ``x_d + dp`` and velocity
    ``xdot_d + dv``; at ``t_blend`` it is ``x_d`` with matching velocity and acceleration.
    The paper's scenario starts 0.21 m away from x_d(0); without the blend the initial
    velocity demand is lambda1 * 0.21 = 8.4 m/s. On a restart after safe mode the velocity
    term avoids an effort step of K_D (xdot - xdot_d).
    """
    if t_blend <= 0.0 or t >= t_blend:
        return ref
    s, T = t / t_blend, t_blend
    h0 = 1.0 - 10 * s**3 + 15 * s**4 - 6 * s**5
    dh0 = (-30 * s**2 + 60 * s**3 - 30 * s**4) / T
    ddh0 = (-60 * s + 180 * s**2 - 120 * s**3) / T**2
    x, v, a = ref.x_d_W + h0 * offset_W, ref.xdot_d_W + dh0 * offset_W, ref.xddot_d_W + ddh0 * offset_W
    if offset_vel_W is not None:
        h1 = T * (s - 6 * s**3 + 8 * s**4 - 3 * s**5)
        dh1 = 1.0 - 18 * s**2 + 32 * s**3 - 15 * s**4
        ddh1 = (-36 * s + 96 * s**2 - 60 * s**3) / T
        x, v, a = x + h1 * offset_vel_W, v + dh1 * offset_vel_W, a + ddh1 * offset_vel_W
    return Reference(x, v, a)
