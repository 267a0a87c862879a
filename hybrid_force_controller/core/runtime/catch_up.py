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
    longer than state_timeout (silent past 2 state_timeout); it ends once each input has
    been current at some tick since it began: at most CAUGHT_UP_PERIODS periods old, or no
    younger than its youngest for PLATEAU_PERIODS periods (its backlog is drained)   (C1)

Silent only past 2 ``state_timeout`` (SILENT_STALLS in controller_runtime.py): a stall of the
loop just over a robot's command watchdog is one the watchdog may not yet have acted on, and
silence then made it act (s53g: a 101 ms stall, the sim's 100 ms watchdog fired 12 ms into the
silence). During a catch-up the runtime stays in safe mode and holds a fresh state as a stale
one (no impedance, no new hold reference from it). During a *silent* one it sends nothing: the
plant goes on as it did through the stall (its watchdog's zero effort or brakes, or the last
command held), which is continuous with what it did, whatever the plant. Each stream is checked on
its own: two 100 Hz streams a few ms apart in phase are never current at the same tick. Ages
are on the controller's clock (sender_clock.py maps each stamp onto it, a constant transport
delay taken out, but learnt slowly: a lag that changed with the fault stays in the ages for
seconds). Hence the plateau: a backlog drains, each sample younger than the last, while a
stream's steady lag does not (the lockstep rig after 0.2 s without joint states: 11.5 ms for
good, and the runtime stayed in safe mode). Pure Python; times are arguments.
"""
from __future__ import annotations

import math

__all__ = ['CAUGHT_UP_PERIODS', 'CatchUp', 'PLATEAU_PERIODS', 'YOUNGER_PERIODS']

CAUGHT_UP_PERIODS = 5  # an input this many control periods old is current (C1)
PLATEAU_PERIODS = 20  # ... or one no younger than its youngest for this long (drained)
YOUNGER_PERIODS = 0.5  # a sample younger than the youngest by this much: still draining


class CatchUp:
    """Whether a catch-up (C1) is under way, and whether it is silent."""

    def __init__(self) -> None:
        self.active = False
        self.silent = False  # after a stall of the loop: nothing is sent until it ends
        self._current = [False, False]  # joint state, wrench: current since it began
        self._youngest = [math.inf, math.inf]  # the youngest age of each since it began, s
        self._since = [0.0, 0.0]  # and the time it was seen, s

    def begin(self, silent: bool) -> None:
        """Begin a catch-up (or begin it again); ``silent`` stays until it ends."""
        self.active, self.silent = True, self.silent or silent
        self._current[0] = self._current[1] = False  # in place: called each stale tick
        self._youngest[0] = self._youngest[1] = math.inf

    def holds_stale(self, age: float, period: float) -> bool:
        """Say whether a state ``age`` s old counts as stale for the hold: not current."""
        return self.active and age > CAUGHT_UP_PERIODS * period

    def reset(self) -> None:
        """Forget it (a restart, a clock restart: the runtime waits for inputs anew)."""
        self.active = self.silent = False

    def done(self, t: float, age_state: float, age_wrench: float, period: float,
             timeout: float) -> bool:
        """
        Note the inputs' ages at ``t`` (s); say whether the catch-up is over.

        ``period`` is the loop's, ``timeout`` the ``state_timeout`` (an older input is never
        current). On a plateau the age must also be within CAUGHT_UP_PERIODS of the youngest:
        a stream that stopped grows older, and is not drained but late.
        """
        limit = CAUGHT_UP_PERIODS * period
        for i, age in enumerate((age_state, age_wrench)):
            if self._current[i]:
                continue
            if age < self._youngest[i] - YOUNGER_PERIODS * period:
                self._youngest[i], self._since[i] = age, t
            plateau = (t - self._since[i] >= PLATEAU_PERIODS * period
                       and age <= self._youngest[i] + limit)
            self._current[i] = age <= limit or (plateau and age <= timeout)
        if self._current[0] and self._current[1]:
            self.reset()
        return not self.active
