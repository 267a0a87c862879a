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
    """
    Start the reference where the arm is (and as fast) and blend into ``ref``.

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
    x, v, a = (ref.x_d_W + h0 * offset_W, ref.xdot_d_W + dh0 * offset_W,
               ref.xddot_d_W + ddh0 * offset_W)
    if offset_vel_W is not None:
        h1 = T * (s - 6 * s**3 + 8 * s**4 - 3 * s**5)
        dh1 = 1.0 - 18 * s**2 + 32 * s**3 - 15 * s**4
        ddh1 = (-36 * s + 96 * s**2 - 60 * s**3) / T
        x, v, a = x + h1 * offset_vel_W, v + dh1 * offset_vel_W, a + ddh1 * offset_vel_W
    return Reference(x, v, a)


class BlendedReference:
    """
    The desired motion of a run: the sine or a held point, blended smoothly on changes.

    Times ``tau`` are seconds since the run started. :meth:`start_from` makes the reference
    begin at the arm's position and velocity; :meth:`switch` changes the base (sine
    parameters, a held point, the normal) while the reference continues from where it
    was. Both blend into the new base over ``t_blend`` with :func:`blend_start`. Only the
    part along the surface is blended; along ``n`` the force loop acts.
    """

    def __init__(self, sine: SineReference, n_W: np.ndarray, t_blend: float) -> None:
        self.sine, self.t_blend = sine, t_blend
        self.P_t = np.eye(3) - np.outer(n_W, n_W)
        self.x_hold_W: np.ndarray | None = None
        self.dp_W, self.dv_W, self.tau_b = np.zeros(3), np.zeros(3), 0.0

    def base(self, tau: float) -> Reference:
        """Return the reference without the blend: the sine, or the held point at rest."""
        if self.x_hold_W is None:
            return self.sine(tau)
        z = np.zeros(3)
        return Reference(self.x_hold_W, z, z)

    def __call__(self, tau: float) -> Reference:
        return blend_start(self.base(tau), self.dp_W, tau - self.tau_b, self.t_blend, self.dv_W)

    def start_from(self, tau: float, x_W: np.ndarray, xdot_W: np.ndarray) -> None:
        """Blend from the position ``x_W`` and velocity ``xdot_W`` at ``tau``."""
        b = self.base(tau)
        self.dp_W, self.dv_W = self.P_t @ (x_W - b.x_d_W), self.P_t @ (xdot_W - b.xdot_d_W)
        self.tau_b = tau

    def switch(self, tau: float, *, sine: SineReference | None = None,
               x_hold_W: np.ndarray | None = None, release: bool = False,
               n_W: np.ndarray | None = None, t_blend: float | None = None) -> None:
        """Change the base at ``tau`` and continue from the current reference."""
        now = self(tau)
        self.sine = self.sine if sine is None else sine
        self.x_hold_W = None if release else (self.x_hold_W if x_hold_W is None else x_hold_W)
        self.t_blend = self.t_blend if t_blend is None else t_blend
        if n_W is not None:
            self.P_t = np.eye(3) - np.outer(n_W, n_W)
        self.start_from(tau, now.x_d_W, now.xdot_d_W)
