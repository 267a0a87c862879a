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
``limit / speed`` (2 s with the defaults), and then the arm holds and reports. The limit
counts from where the surface was last touched when the tool is now short of it
(``x_seen``): an arm thrown back off the surface (a stall's fall bounced it 5 cm up, seen
in real time) goes back to it and ``limit`` beyond, instead of giving up in mid-air.

The reference moves in absolute terms: it never waits for the tool, so ``limit`` counts
real travel in space and the search ends in a bounded time whatever the model. What it
demands of the tool is bounded instead: the law tracks the reference clipped to at most
``LAG_M`` ahead of the tool, so a tool held back (a model error along n) does not build
up a demand that it would release at impact. An earlier version held the reference
itself to the tool: with theta_hat 2.6 times too heavy the gravity over-compensation
held the tool off, the reference never moved, and the search "hovered" for 15 s.

:class:`Handover` fades what the approach demanded of r along n into the force loop's
when contact is found (bumpless).
"""
from __future__ import annotations

import math

from .bumpless import cosine_fade
from .control_law import ApproachRef

__all__ = ['Approach', 'HANDOVER_S', 'Handover']

RAMP_S = 0.1  # time to reach the approach speed from rest, s
LAG_M = 0.005  # the law tracks the reference clipped to this far ahead of the tool, m
HANDOVER_S = 0.02  # approach -> force loop: the normal r and rdot blend over this, s


class Approach:
    """Trapezoidal motion along n from ``start`` for at most ``limit`` metres."""

    def __init__(self, speed: float, limit: float) -> None:
        self.configure(speed, limit)
        self.x0 = self.x = self.v = self.a = self.end = 0.0
        self.exhausted = False

    def configure(self, speed: float, limit: float) -> None:
        self.speed, self.limit = speed, limit
        self.a_max = max(speed, 1e-6) / RAMP_S

    def start(self, x_n: float, v_n: float, x_seen: float = -math.inf) -> None:
        """
        Begin at position ``x_n`` (m along n) with velocity ``v_n`` (m/s).

        The velocity is clipped into ``[0, speed]``. The search ends ``limit`` beyond
        ``max(x_n, x_seen)``, ``x_seen`` where the surface was last touched (m along n).
        """
        self.x0, self.x, self.a, self.exhausted = x_n, x_n, 0.0, False
        self.end = max(x_n, x_seen) + self.limit
        self.v = min(max(v_n, 0.0), self.speed)

    def step(self, dt: float, x_n: float) -> ApproachRef:
        """
        Advance ``dt`` seconds (>= 0) with the tool at ``x_n``; return what the law tracks.

        The reference moves on whatever the tool does (module docstring); the law tracks it
        clipped to ``LAG_M`` ahead of the tool (5 mm: ``K_D lambda1 LAG_M`` of force, 12 N
        with the defaults, to overcome a model error).
        """
        if not self.exhausted:
            self._advance(dt, self.end)
        return ApproachRef(min(self.x, x_n + LAG_M), self.v, self.a)

    def _advance(self, dt: float, end: float) -> None:
        """Move the reference ``dt`` seconds along its trapezoid toward ``end``."""
        remaining = end - self.x
        braking = self.v > 0.0 and remaining <= self.v * self.v / (2.0 * self.a_max) + 1e-12
        target = 0.0 if braking or remaining <= 0.0 else self.speed
        dv = min(max(target - self.v, -self.a_max * dt), self.a_max * dt)
        x = self.x + (self.v + 0.5 * dv) * dt
        if x >= end or (braking and self.v + dv <= 0.0):
            self.x, self.v, self.a, self.exhausted = min(x, end), 0.0, 0.0, True
            return
        self.x, self.v, self.a = x, self.v + dv, dv / dt if dt > 0.0 else 0.0

    @property
    def travel(self) -> float:
        return self.x - self.x0


class Handover:
    """
    Bumpless hand-over from an approach to the force loop.

    What the approach demanded of r and rdot along n (their gaps to the force loop's at
    contact) fades with a cosine over HANDOVER_S: r and rdot stay continuous, so the effort
    does, with no integral wind-up.
    """

    def __init__(self) -> None:
        self.t_c, self.dr, self.drdot = -math.inf, 0.0, 0.0

    def start(self, t: float, dr: float, drdot: float) -> None:
        """Begin at time ``t`` with the gaps ``dr`` (m/s) and ``drdot`` (m/s^2)."""
        self.t_c, self.dr, self.drdot = t, dr, drdot

    def bias(self, t: float) -> tuple[float, float]:
        """Return the part of the gaps left at time ``t`` (zero after HANDOVER_S)."""
        w = cosine_fade((t - self.t_c) / HANDOVER_S)
        return w * self.dr, w * self.drdot
