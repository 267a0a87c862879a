"""
Desired motion x_d(t) with its derivatives (section V of [1]), pure numpy.

With ``tick_impl: compiled`` the runtime gives :class:`BlendedReference` the same sums as a
numba kernel (step_kernels.reference_rows); nothing here imports numba.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any, NamedTuple

import numpy as np

__all__ = ['CORRECT_ACCEL', 'CORRECT_VEL_S', 'H0_PEAK', 'Reference', 'SineReference',
           'blend_start']

CORRECT_VEL_S = 0.25  # correct_from blends the arm's extra velocity out over this, s
CORRECT_ACCEL = 2.0  # correct_from's position part accelerates at most half this, m/s^2
H0_PEAK = 5.78  # the peak of the quintic blend's |H0''| (_hermite), 10/sqrt(3) rounded up


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

    def __post_init__(self) -> None:
        # rows (x_d, xdot_d, xddot_d) = K (1, sin wt, cos wt): one product per evaluation
        w, a = self.omega, np.asarray(self.amplitude_W, dtype=float)
        K = np.zeros((3, 3, 3))
        K[0, :, 0], K[0, :, 1], K[1, :, 2], K[2, :, 1] = self.center_W, a, w * a, -w * w * a
        object.__setattr__(self, '_K', K)

    def rows(self, t: float) -> np.ndarray:
        """Return x_d, xdot_d and xddot_d at time ``t`` (s) as the rows of a new (3, 3) array."""
        wt = self.omega * t
        return self._K.dot((1.0, math.sin(wt), math.cos(wt)))

    def __call__(self, t: float) -> Reference:
        """Evaluate at time ``t`` (s)."""
        rows = self.rows(t)
        return Reference(rows[0], rows[1], rows[2])


def _hermite(t: float, t_blend: float) -> np.ndarray:
    """
    Return the blend weights of :func:`blend_start` at ``t``, a (3, 2) array.

    Rows: value, first and second time derivative; columns: ``H0(s)`` and ``t_blend H1(s)``.
    """
    s, T = t / t_blend, t_blend
    return np.array((
        (1.0 - 10 * s**3 + 15 * s**4 - 6 * s**5, T * (s - 6 * s**3 + 8 * s**4 - 3 * s**5)),
        ((-30 * s**2 + 60 * s**3 - 30 * s**4) / T, 1.0 - 18 * s**2 + 32 * s**3 - 15 * s**4),
        ((-60 * s + 180 * s**2 - 120 * s**3) / T**2, (-36 * s + 96 * s**2 - 60 * s**3) / T)))


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
    dv = np.zeros(3) if offset_vel_W is None else offset_vel_W
    rows = np.array(ref) + _hermite(t, t_blend).dot(np.array((offset_W, dv)))
    return Reference(rows[0], rows[1], rows[2])


class BlendedReference:
    """
    The desired motion of a run: the sine, a held point or a path, blended smoothly on changes.

    Times ``tau`` are seconds since the run started. :meth:`start_from` makes the reference
    begin at the arm's position and velocity; :meth:`switch` changes the base (sine
    parameters, a held point, a path, the normal) while the reference continues from where it
    was. Both blend into the new base over ``t_blend`` (or a duration of their own,
    ``blend_s``) as :func:`blend_start` does. :meth:`correct_from` (a stall, the end of safe
    mode) starts from the arm too, but blends back onto the reference as it goes on: a blend
    under way keeps its course, and only the arm's deviation from it is blended out (its
    position within ``t_blend`` at most 1 m/s^2, its velocity over ``CORRECT_VEL_S``). Only
    the part along the surface is blended; along ``n`` the force loop acts. A path is any
    object whose ``rows(tau)`` returns the rows x_d, xdot_d, xddot_d as a new (3, 3) array (it
    keeps its own clock).
    """

    #: ``tick_impl: compiled``: step_kernels.reference_rows computes :meth:`rows` (None: numpy)
    kernel: Any = None

    def __init__(self, sine: SineReference, n_W: np.ndarray, t_blend: float) -> None:
        self.sine, self.t_blend = sine, t_blend
        self.P_t = np.eye(3) - np.outer(n_W, n_W)
        self.x_hold_W: np.ndarray | None = None
        self.path: Any = None
        self.dp_W, self.dv_W, self.tau_b = np.zeros(3), np.zeros(3), 0.0
        self._tb = t_blend  # the current blend's duration
        self._offsets = np.zeros((2, 3))  # rows dp_W, dv_W
        self._corr = np.zeros((2, 3))  # correct_from's offsets from the blended reference
        self._corr_tau = -math.inf  # its start (-inf: none)
        self._corr_tp = 0.0  # the duration of its position part

    def _base_rows(self, tau: float) -> np.ndarray:
        """Return the base (the sine, the held point at rest, the path) as rows of a new array."""
        if self.path is not None:
            return self.path.rows(tau)
        if self.x_hold_W is None:
            return self.sine.rows(tau)
        rows = np.zeros((3, 3))
        rows[0] = self.x_hold_W
        return rows

    def base(self, tau: float) -> Reference:
        """Return the reference without the blend: the sine, the held point or the path."""
        rows = self._base_rows(tau)
        return Reference(rows[0], rows[1], rows[2])

    def __call__(self, tau: float) -> Reference:
        rows = self.rows(tau)
        return Reference(rows[0], rows[1], rows[2])

    def rows(self, tau: float) -> np.ndarray:
        """Return the reference at ``tau``: the rows x_d, xdot_d, xddot_d of a new (3, 3) array."""
        if self.kernel is not None:  # the same sums, compiled (tick_impl.py)
            rows, sine = np.empty((3, 3)), self.path is None and self.x_hold_W is None
            base = rows if sine else self._base_rows(tau)
            self.kernel(self.sine._K, self.sine.omega, sine, base, tau, self.tau_b, self._tb,
                        self._offsets, self._corr_tau, self._corr_tp, self._corr, rows)
            return rows
        rows, t = self._base_rows(tau), tau - self.tau_b
        if not (self._tb <= 0.0 or t >= self._tb):  # blending (blend_start)
            rows += _hermite(t, self._tb).dot(self._offsets)
        t = tau - self._corr_tau  # a correction (correct_from); inf without one
        if 0.0 <= t < CORRECT_VEL_S:
            rows += _hermite(t, CORRECT_VEL_S)[:, 1:2] * self._corr[1]
        if 0.0 <= t < self._corr_tp:
            rows += _hermite(t, self._corr_tp)[:, 0:1] * self._corr[0]
        return rows

    def start_from(self, tau: float, x_W: np.ndarray, xdot_W: np.ndarray,
                   blend_s: float | None = None) -> None:
        """Blend from the position ``x_W`` and velocity ``xdot_W`` at ``tau`` over ``blend_s``."""
        b = self.base(tau)
        self.dp_W, self.dv_W = self.P_t @ (x_W - b.x_d_W), self.P_t @ (xdot_W - b.xdot_d_W)
        self._offsets = np.array((self.dp_W, self.dv_W))
        self.tau_b = tau
        self._tb = self.t_blend if blend_s is None else blend_s
        self._corr_tau = -math.inf  # a new blend replaces a correction

    def correct_from(self, tau: float, x_W: np.ndarray, xdot_W: np.ndarray) -> None:
        """
        Blend from ``x_W``, ``xdot_W`` at ``tau`` back onto the reference as it goes on.

        The position's offset dp blends out over ``T_p = sqrt(2 H0_PEAK |dp| / CORRECT_ACCEL)``
        (peak acceleration ``CORRECT_ACCEL / 2``) within [``CORRECT_VEL_S``, ``t_blend``], the
        velocity's over :data:`CORRECT_VEL_S`: ``x_c = H0(t / T_p) dp + T_v H1(t / T_v) dv``
        (start: the arm's position and velocity, zero acceleration; end: the reference), so the
        arm's own velocity carries it at most ``16/81 T_v |dv|`` (5 cm per m/s; peak
        deceleration ``3.94 |dv| / T_v``). Restarting the blend under way instead
        (:meth:`start_from`) carried the arm's velocity into a fresh ``t_blend``: stalls
        during the paper's start-up blend, the arm at 0.22 m/s, took the reference 9 cm past
        the sine's end, to the arm's full reach. A 2 s return of the position alone, after
        1 s of NaN joint states had left the arm 17 cm off, met the sine going out to its end:
        the reference stayed within 1 cm of full reach for 1 s (test_recovery.py).
        """
        self._corr_tau = -math.inf  # the reference without the correction under way
        now = self.rows(tau)
        self._corr = np.array((self.P_t @ (x_W - now[0]), self.P_t @ (xdot_W - now[1])))
        T_p = self.t_blend
        if T_p > 0.0:
            dp = float(np.linalg.norm(self._corr[0]))
            T_p = min(max(math.sqrt(2.0 * H0_PEAK * dp / CORRECT_ACCEL), CORRECT_VEL_S), T_p)
        self._corr_tau, self._corr_tp = tau, T_p

    def switch(self, tau: float, *, sine: SineReference | None = None,
               x_hold_W: np.ndarray | None = None, path: Any = None, release: bool = False,
               n_W: np.ndarray | None = None, t_blend: float | None = None,
               blend_s: float | None = None) -> None:
        """
        Change the base at ``tau`` and continue from the current reference.

        ``release`` drops a held point and a path (back to the sine); a held point replaces a
        path and a path a held point. ``blend_s`` is this blend's duration (default
        ``t_blend``).
        """
        now = self(tau)
        self.sine = self.sine if sine is None else sine
        if release or x_hold_W is not None or path is not None:
            self.x_hold_W, self.path = x_hold_W, path
        self.t_blend = self.t_blend if t_blend is None else t_blend
        if n_W is not None:
            self.P_t = np.eye(3) - np.outer(n_W, n_W)
        self.start_from(tau, now.x_d_W, now.xdot_d_W, blend_s)
