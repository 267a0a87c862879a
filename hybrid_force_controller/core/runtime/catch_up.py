"""
The catch-up after stale inputs or a stall of the loop: when the inputs are current again.

Inputs older than ``state_timeout`` put the runtime in safe mode (controller_runtime.py); they
are *fresh* again once younger than that. But fresh is not current. After a stall the samples
sent meanwhile come oldest first (the middleware drains a socket's backlog; over DDS the first
joint state after a 300 ms freeze of the controller was 300 ms old), so for a while every
sample is a few tens of ms old, each younger than the last. A hold or a law that starts from
those starts from where the arm *was*. And after a freeze of the controller longer than the
plant's command watchdog, the plant has been applying zero effort (or its brakes): sending the
hold's effort at once, on a state 100-300 ms old, was a step from zero to the weight of the arm
while the arm lay pressed into the surface by its fall. The surface's spring then flung it off
(offline, the backlog replayed at 1.5-3 samples per ms: 9 cm above the surface, not found
again within 3 s; docs/results.md section 30).

:class:`CatchUp` keeps the runtime's rule::

    a catch-up begins when the inputs go stale (safe mode), or after a stall of the loop
    longer than state_timeout (silent); it ends once each input has been at most
    CAUGHT_UP_PERIODS periods old at some tick since it began                    (C1)

During a catch-up the runtime stays in safe mode and holds a fresh state as a stale one (no
impedance, no new hold reference from it). During a *silent* one it sends nothing: the plant
goes on as it did through the stall (its watchdog's zero effort or brakes, or the last command
held), which is continuous with what it did, whatever the plant. Each stream is checked on
its own: two 100 Hz streams a few ms apart in phase are never current at the same tick. Ages
are on the controller's clock (sender_clock.py maps each stamp onto it, a constant transport
delay taken out). Pure Python; times are arguments.
"""
from __future__ import annotations

__all__ = ['CAUGHT_UP_PERIODS', 'CatchUp']

CAUGHT_UP_PERIODS = 5  # an input this many control periods old is current (C1)


class CatchUp:
    """Whether a catch-up (C1) is under way, and whether it is silent."""

    def __init__(self) -> None:
        self.active = False
        self.silent = False  # after a stall of the loop: nothing is sent until it ends
        self._current = [False, False]  # joint state, wrench: current since it began

    def begin(self, silent: bool) -> None:
        """Begin a catch-up (or begin it again); ``silent`` stays until it ends."""
        self.active, self.silent = True, self.silent or silent
        self._current = [False, False]

    def reset(self) -> None:
        """Forget it (a restart, a clock restart: the runtime waits for inputs anew)."""
        self.active = self.silent = False

    def done(self, age_state: float, age_wrench: float, limit: float) -> bool:
        """Note the inputs' ages (s) against ``limit``; say whether the catch-up is over."""
        cur = self._current
        cur[0] = cur[0] or age_state <= limit
        cur[1] = cur[1] or age_wrench <= limit
        if cur[0] and cur[1]:
            self.reset()
        return not self.active
