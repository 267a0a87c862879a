"""
Approach: out of contact, the normal reference moves toward the surface (pure numpy).

The paper's law regains a lost surface only through ``c lambda1 f_d`` (1/6000 * 40 * 1 N =
6.7 mm/s) because the force integral is frozen out of contact. Instead, the runtime hands
the normal direction to an :class:`Approach`: a position reference along n that starts
where the tool is, with the velocity it had, ramps to ``speed`` at a bounded
acceleration, and stops (decelerating) after ``limit`` metres of travel: the surface was
not found there. Its time steps come from the caller.

Why a distance limit: the surface was last seen where contact was lost (or, at start-up,
near the tool); a surface that moved further than ``approach_limit`` is a changed scene
(a removed workpiece, a wrong ``n``), and pressing on into free space would only end in a
collision at speed. So the search is bounded in distance, which bounds its time as
``limit / speed`` (2 s with the defaults), and then the arm holds and reports.
"""
from __future__ import annotations

from .control_law import ApproachRef

__all__ = ['Approach']

RAMP_S = 0.1  # time to reach the approach speed from rest, s
LAG_M = 0.005  # the reference waits for a tool that lags it by more than this, m


class Approach:
    """Trapezoidal motion along n from ``start`` for at most ``limit`` metres."""

    def __init__(self, speed: float, limit: float) -> None:
        self.configure(speed, limit)
        self.x0 = self.x = self.v = 0.0
        self.exhausted = False

    def configure(self, speed: float, limit: float) -> None:
        self.speed, self.limit = speed, limit
        self.a_max = max(speed, 1e-6) / RAMP_S

    def start(self, x_n: float, v_n: float) -> None:
        """
        Begin at position ``x_n`` (m along n) with velocity ``v_n`` (m/s).

        The velocity is clipped into ``[0, speed]``.
        """
        self.x0, self.x, self.exhausted = x_n, x_n, False
        self.v = min(max(v_n, 0.0), self.speed)

    def step(self, dt: float, x_n: float) -> ApproachRef:
        """
        Advance ``dt`` seconds (>= 0) with the tool at ``x_n``; return the reference.

        The reference never leads the tool by more than ``LAG_M`` (5 mm: ``K_D lambda1
        LAG_M`` of force, 12 N with the defaults, to overcome a model error), so a tool
        held back does not build up a demand that it would release at impact.
        """
        end = self.x0 + self.limit
        self.x = min(self.x, x_n + LAG_M)
        if self.exhausted:
            return ApproachRef(self.x, 0.0, 0.0)
        remaining = end - self.x
        braking = self.v > 0.0 and remaining <= self.v * self.v / (2.0 * self.a_max) + 1e-12
        target = 0.0 if braking or remaining <= 0.0 else self.speed
        dv = min(max(target - self.v, -self.a_max * dt), self.a_max * dt)
        x = self.x + (self.v + 0.5 * dv) * dt
        if x >= end or (braking and self.v + dv <= 0.0):
            self.x, self.v, self.exhausted = min(x, end), 0.0, True
            return ApproachRef(self.x, 0.0, 0.0)
        self.x, self.v = x, self.v + dv
        return ApproachRef(self.x, self.v, dv / dt if dt > 0.0 else 0.0)

    @property
    def travel(self) -> float:
        return self.x - self.x0
