"""
A path being followed: the plan and its own clock (pure numpy; the control thread, O(1)).

The path's time sigma advances only while the runtime runs the force loop in contact
(contact first: a path received out of contact waits while the approach finds the surface,
and it stands still in safe mode). It starts and stops smoothly: its rate
``sigmadot = 3 rho^2 - 2 rho^3`` follows ``rho``, which moves toward 1 (go) or 0 (wait) at
``1 / ramp_s``, so with ``x_d(t) = p(sigma(t))``

    xdot_d = p' sigmadot,   xddot_d = p'' sigmadot^2 + p' sigmaddot

stay continuous when the tool waits mid-path (a contact loss) and goes on (sigmaddot is 0 at
both ends of a ramp, and at most ``1.5 / ramp_s``; ``ramp_s = 1.5 v_peak / a_max`` keeps
``p' sigmaddot`` within ``a_max``). Before the path has moved (sigma = 0) it is at rest with
zero acceleration, so rho may jump there.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..law.path import PathPlan

__all__ = ['PATH_DONE', 'PATH_IDLE', 'PATH_RUNNING', 'PATH_STOPPED', 'PATH_WAITING',
           'PathProgress', 'PathRun']

PATH_IDLE, PATH_WAITING, PATH_RUNNING = 'idle', 'waiting for contact', 'running'
PATH_DONE, PATH_STOPPED = 'done', 'stopped'
RAMP_MIN_S = 0.02


class PathProgress(NamedTuple):
    """A path's state for the node: its number, state, fraction done and time left (s)."""

    seq: int
    state: str
    fraction: float
    time_left_s: float


IDLE = PathProgress(0, PATH_IDLE, 0.0, 0.0)


class PathRun:
    """A :class:`~..law.path.PathPlan` with its clock (module docstring)."""

    def __init__(self, plan: PathPlan, seq: int, a_max: float) -> None:
        self.plan, self.seq = plan, seq
        self.sigma = self.rho = self.rho_rate = 0.0
        self.ramp_s = max(RAMP_MIN_S, 1.5 * plan.v_peak / a_max)
        self.going = False

    @property
    def done(self) -> bool:
        return self.sigma >= self.plan.duration

    def advance(self, dt: float, go: bool) -> None:
        """Advance the clock by ``dt`` s of the run (``go``: running in contact)."""
        self.going = go
        r = self.rho
        sdot0 = r * r * (3.0 - 2.0 * r)
        if self.sigma <= 0.0:  # at rest, zero acceleration: may start at full rate
            self.rho, self.rho_rate = (1.0 if go else 0.0), 0.0
            sdot0 = self.rho
        else:
            target = 1.0 if go else 0.0
            step = dt / self.ramp_s
            rho = min(self.rho + step, 1.0) if go else max(self.rho - step, 0.0)
            self.rho_rate = 0.0 if rho == target else (1.0 if go else -1.0) / self.ramp_s
            self.rho = rho
        r = self.rho  # the trapezoidal rule: sigma follows sigmadot to second order
        sdot = r * r * (3.0 - 2.0 * r)
        self.sigma = min(self.sigma + 0.5 * (sdot0 + sdot) * dt, self.plan.duration)

    def pause(self) -> None:
        """Stand still from now on (safe mode): the next start ramps up again."""
        self.rho = self.rho_rate = 0.0
        self.going = False

    def rows(self, tau: float = 0.0) -> np.ndarray:
        """Return x_d, xdot_d, xddot_d (a new (3, 3) array); ``tau`` is not used (own clock)."""
        r = self.rho
        if r == 1.0:
            return self.plan.rows(self.sigma)
        return self.plan.rows(self.sigma, r * r * (3.0 - 2.0 * r),
                              6.0 * r * (1.0 - r) * self.rho_rate)

    def progress(self) -> PathProgress:
        """Return the state, fraction done and time left (at the plan's rate)."""
        d = self.plan.duration
        state = PATH_DONE if self.done else (PATH_RUNNING if self.going else PATH_WAITING)
        return PathProgress(self.seq, state, self.sigma / d if d > 0.0 else 1.0,
                            d - self.sigma)
