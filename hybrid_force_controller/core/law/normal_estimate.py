"""
Online estimate of the surface normal n from the measured contact force (issue 24, item 1).

The paper's S = n n^T (14) assumes n known and constant; a workpiece's pose and shape are only
roughly known. Following Yoshikawa & Sudou (1993) and Nasiri & Wang (2024), the force the tool
exerts on the surface is its normal part plus kinetic friction along the sliding velocity::

    f = f_n n + mu f_n u,    u = v / |v|,  v the tool's velocity (tangent to the surface)  (N1)

Per sample, in the base frame, with ``n_hat`` the current estimate (equations (N1)-(N6) are
this module's; docs/design.md, "A moving normal", gives the stability bound of its rate)::

    f_u = f^T u,   f_perp = f - f_u u                      (the parts along and across v)
    mu_hat <- mu_hat + a_mu (clip(f_u / |f_perp|, 0, MU_MAX) - mu_hat),
              a_mu = 1 - exp(-dt / T_mu)                                               (N2)
    f_c = f - mu_hat |f_perp| u            (friction removed; f_c = f when removal is off)  (N3)
    f_c <- f_c - w (f_c^T u) u             (fused with n perpendicular to v, weight w)     (N4)
    n_m = f_c / |f_c|                                           (the measured normal)      (N5)
    n_hat <- n_hat turned towards n_m by min(phi (1 - exp(-dt / T_n)), omega_max dt),
             phi = angle(n_hat, n_m)                                                     (N6)

(N6) is a first-order follow with time constant T_n whose rate is limited to ``omega_max``
(``rate_limit``): n_hat rotates at most omega_max rad/s whatever is measured, and stays unit
(a rotation, renormalised). With w = 1 (N4) removes the whole component along v (Yoshikawa's
estimate; it needs v tangent to the surface); w = 0 relies on mu_hat alone (Nasiri & Wang).

**A seated pad** (``orientation_mode`` moment, law/orientation.py :meth:`seated_axis`). A flat
pad whose tilt moments are at their target lies flat on the part: its axis ``a_W`` (the tool
axis, into the surface) is the normal at the contact, at rest as well as sliding, and without
the friction's ambiguity. While the caller says the pad is seated its axis is the measurement::

    n_m = a_W      (the pad seated: its centre of pressure within seat_offset of its centre)  (N7)

and (N6) turns n_hat towards it at once (``a_n = 1``: the axis is not noisy; the rate limit
holds). mu_hat is learnt on (N2) while the seated pad slides, so that the force's measurement is
ready when the pad leaves its seat (the pad's axis lags a normal that turns under it, the
moment's admittance, and a tilt moment beyond seat_offset then unseats it).

**Gates.** A sample updates nothing unless the tool is in contact (the caller's test), the force
``|f|`` is at least ``force_floor`` and it is finite. It updates mu_hat and n_hat only while
*sliding*: the speed across n_hat, ``|v - (v^T n_hat) n_hat|``, at least ``speed_floor``.

**At rest** n_hat and mu_hat are held. Static friction can then hold any tangential force up to
mu_s f_n in any direction: the force may lean by up to ``atan(mu_s)`` from the normal (17 deg at
mu = 0.3, 27 deg at 0.5) and tells nothing more precise, so it is not used. Before the first
sliding sample n_hat is the initial guess (the ``n`` parameter); mu_hat starts at 0 (until it is
learnt, the measurement leans by up to atan(mu) and n_hat moves towards it at most omega_max).

**Never wrong in kind.** n_hat is always a finite unit vector: non-finite inputs are counted and
ignored, a measurement opposite the estimate (``n_m^T n_hat <= 0``: a force pulling on the
surface) is refused, a degenerate one (``|f_c|`` ~ 0) is skipped. Pure Python on floats: time is
an argument, nothing reads a clock, nothing is allocated per sample beyond floats.
"""
from __future__ import annotations

import math
from typing import Sequence

from ..config.groups import NormalConfig, NormalConfigError, NormalEstimateError

__all__ = ['MU_MAX', 'NormalConfig', 'NormalConfigError', 'NormalEstimateError',
           'NormalEstimator']

MU_MAX = 2.0  # largest friction coefficient one sample may suggest (N2)
_TINY = 1e-12


def _unit(x: Sequence[float], what: str) -> tuple[float, float, float]:
    """Return ``x`` normalised, or raise NormalEstimateError for a zero or non-finite 3-vector."""
    try:
        a, b, c = (float(v) for v in x)
    except (TypeError, ValueError):
        raise NormalEstimateError(f'{what} must be 3 numbers, got {x!r}') from None
    norm = math.sqrt(a * a + b * b + c * c)
    if not (math.isfinite(norm) and norm > 1e-9):
        raise NormalEstimateError(f'{what} must be a non-zero finite 3-vector, got {x!r}')
    return a / norm, b / norm, c / norm


class NormalEstimator:
    """
    The surface normal n_hat from force and velocity, (N1)-(N6) of the module docstring.

    Call :meth:`update` once per new state with the filtered contact force the tool exerts on
    the surface and the tool's velocity, both in the base frame; read :attr:`n_hat`.
    """

    def __init__(self, config: NormalConfig, n0: Sequence[float]) -> None:
        if not isinstance(config, NormalConfig):
            raise NormalConfigError(f'expected a NormalConfig, got {type(config).__name__}')
        self.config = config
        self._floors = (config.force_floor ** 2, config.speed_floor ** 2)  # squared, per sample
        self._dt_cache = (-1.0, 0.0, 0.0, 0.0)  # dt, a_n (N6), a_mu (N2), omega_max dt
        self.reset(n0)

    def reset(self, n0: Sequence[float], mu0: float = 0.0) -> None:
        """Restart from the initial guess ``n0`` (any length) and ``mu0``; counters to zero."""
        self._n = _unit(n0, 'n0')
        self.mu_hat = float(mu0)
        self.state = 'initial'  # what the last sample did (see update)
        self.samples_used = self.samples_rejected = 0
        self.last_angle = 0.0  # angle n_hat turned by on the last sample, rad

    def reconfigure(self, config: NormalConfig) -> None:
        """Install new settings; the estimate and mu_hat are kept."""
        if not isinstance(config, NormalConfig):
            raise NormalConfigError(f'expected a NormalConfig, got {type(config).__name__}')
        self.config, self._dt_cache = config, (-1.0, 0.0, 0.0, 0.0)
        self._floors = (config.force_floor ** 2, config.speed_floor ** 2)

    @property
    def n_hat(self) -> tuple[float, float, float]:
        """Return the estimate: a finite unit vector into the surface, base frame."""
        return self._n

    def _factors(self, dt: float) -> tuple[float, float, float, float]:
        """Return the factors of ``dt`` (cached: stamps' differences differ in the last bits)."""
        cached = self._dt_cache[0]
        if not abs(dt - cached) <= 1e-9 * cached:
            if not (isinstance(dt, (int, float)) and math.isfinite(dt) and dt > 0.0):
                raise NormalEstimateError(f'dt must be finite and > 0, got {dt!r}')
            c = self.config
            self._dt_cache = (dt, -math.expm1(-dt / c.time_constant),
                              -math.expm1(-dt / c.friction_time_constant), c.rate_limit * dt)
        return self._dt_cache

    def update(self, f_W: Sequence[float], v_W: Sequence[float], dt: float,
               in_contact: bool, axis_W: Sequence[float] | None = None) -> bool:
        """
        Feed one sample; return True when n_hat moved towards a new measurement.

        ``state`` says what the sample did: ``no_contact``, ``low_force``, ``at_rest``,
        ``implausible`` (opposite the estimate, or degenerate), ``rejected`` (non-finite),
        ``sliding`` (used) or ``seated`` (the pad's axis used, (N7)).

        Parameters
        ----------
        f_W : sequence of 3 floats
            The force the tool exerts on the surface, base frame, N (filtered).
        v_W : sequence of 3 floats
            The tool's velocity, base frame, m/s.
        dt : float
            Time since the previous sample, s (finite, > 0; else NormalEstimateError).
        in_contact : bool
            The caller's contact test.
        axis_W : sequence of 3 floats, optional
            The seated pad's unit axis, into the surface, base frame (N7); None: not seated.

        """
        _, a_n, a_mu, step_max = self._factors(dt)
        f0, f1, f2 = f_W
        v0, v1, v2 = v_W
        if not math.isfinite(f0 + f1 + f2 + v0 + v1 + v2):
            self.samples_rejected += 1
            return self._hold('rejected')
        if not in_contact:
            return self._hold('no_contact')
        if f0 * f0 + f1 * f1 + f2 * f2 < self._floors[0]:
            return self._hold('low_force')
        n0, n1, n2 = self._n
        v_n = v0 * n0 + v1 * n1 + v2 * n2
        t0, t1, t2 = v0 - v_n * n0, v1 - v_n * n1, v2 - v_n * n2
        sliding = t0 * t0 + t1 * t1 + t2 * t2 >= self._floors[1]
        if sliding:
            speed = math.sqrt(v0 * v0 + v1 * v1 + v2 * v2)
            u0, u1, u2 = v0 / speed, v1 / speed, v2 / speed
            c0, c1, c2 = self._measured(f0, f1, f2, u0, u1, u2, a_mu)  # (N2)-(N4)
        if axis_W is not None:  # (N7); mu_hat learnt on while sliding, for when it unseats
            return self._seated(axis_W, step_max)
        if not sliding:
            return self._hold('at_rest')
        norm = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
        if not norm > _TINY or c0 * n0 + c1 * n1 + c2 * n2 <= 0.0:
            return self._hold('implausible')
        self._turn(c0 / norm, c1 / norm, c2 / norm, a_n, step_max)  # (N5), (N6)
        self.samples_used += 1
        self.state = 'sliding'
        return True

    def _seated(self, axis_W: Sequence[float], step_max: float) -> bool:
        """(N7), (N6): turn n_hat towards the seated pad's axis; refuse one opposite it."""
        a0, a1, a2 = axis_W
        norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        n0, n1, n2 = self._n
        if not (math.isfinite(norm) and norm > _TINY) or a0 * n0 + a1 * n1 + a2 * n2 <= 0.0:
            return self._hold('implausible')
        self._turn(a0 / norm, a1 / norm, a2 / norm, 1.0, step_max)
        self.samples_used += 1
        self.state = 'seated'
        return True

    def _hold(self, state: str) -> bool:
        self.state, self.last_angle = state, 0.0
        return False

    def _measured(self, f0: float, f1: float, f2: float, u0: float, u1: float, u2: float,
                  a_mu: float) -> tuple[float, float, float]:
        """(N2)-(N4): update mu_hat; return the force with friction removed and v fused."""
        c = self.config
        f_u = f0 * u0 + f1 * u1 + f2 * u2
        p0, p1, p2 = f0 - f_u * u0, f1 - f_u * u1, f2 - f_u * u2
        f_perp = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        if f_perp > _TINY:  # (N2)
            self.mu_hat += a_mu * (min(max(f_u / f_perp, 0.0), MU_MAX) - self.mu_hat)
        if c.friction_removal:  # (N3)
            f_u -= self.mu_hat * f_perp
        f_u *= 1.0 - c.velocity_fusion  # (N4): what remains along u
        return p0 + f_u * u0, p1 + f_u * u1, p2 + f_u * u2

    def _turn(self, m0: float, m1: float, m2: float, a_n: float, step_max: float) -> None:
        """(N6): turn n_hat towards the unit m by a rate-limited first-order step."""
        n0, n1, n2 = self._n
        cos_phi = n0 * m0 + n1 * m1 + n2 * m2
        e0, e1, e2 = m0 - cos_phi * n0, m1 - cos_phi * n1, m2 - cos_phi * n2
        sin_phi = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        phi = math.atan2(sin_phi, cos_phi)
        step = min(phi * a_n, step_max)
        if not (sin_phi > _TINY and step > 0.0):
            self.last_angle = 0.0
            return
        c, s = math.cos(step), math.sin(step) / sin_phi  # e / sin_phi: unit, across n_hat
        n0, n1, n2 = c * n0 + s * e0, c * n1 + s * e1, c * n2 + s * e2
        norm = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2)
        self._n = (n0 / norm, n1 / norm, n2 / norm)
        self.last_angle = step
