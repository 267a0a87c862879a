"""
The run's times: its origin, the latest tick, the state the last integration used (pure Python).

A run's reference time (``tau``) starts at the stamp of its first joint state and stands still
while safe mode holds the tool (:meth:`RunClock.pause`, :meth:`RunClock.resume`). theta_hat and
h integrate over the time between consecutive *new* joint states (:meth:`RunClock.state_step`),
never across a gap (a stall, a restart). Times are seconds on the caller's clock.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

__all__ = ['RunClock']


@dataclass
class RunClock:
    """
    The run's times, s.

    ``t0`` the stamp of its first state (the reference's origin, moved on by the time spent in
    safe mode), the latest tick, and the stamp of the state the last integration used.
    """

    t0: float | None = None
    t_tick: float = -math.inf
    t_used: float = -math.inf
    t_pause: float | None = None  # the reference's time stopped here (safe mode's entry)

    def tau(self, t_state: float) -> float:
        """Return the reference's time at the state stamped ``t_state`` (0 before the start)."""
        return 0.0 if self.t0 is None else t_state - self.t0

    def resume(self, t_state: float, after_pause: bool) -> None:
        """
        Start the run at ``t_state``, or go on after a pause (the time held stands still).

        After safe mode the reference goes on from where it paused: its time stood still
        during the hold, so the task is not cut short and the blend has no distance to catch
        up (a sine that ran on moved the force by up to 0.25 N while catching up).
        """
        if self.t0 is None:
            self.t0 = t_state
        elif after_pause and self.t_pause is not None:
            self.t0 += max(t_state - self.t_pause, 0.0)
        self.t_pause = None

    def pause(self, t_state: float) -> None:
        """Stop the reference's time at ``t_state`` (safe mode's entry)."""
        self.t_pause = t_state

    def state_step(self, t_state: float, gap: bool, period: float,
                   limit: float) -> tuple[float, float, str]:
        """
        Return the time since the state the last integration used, the part to integrate, why.

        The time is 0 if no state is new (why: ``'stale'``), or after a gap (a stall or a
        restart: nothing integrates across it, nor does the stiffness estimate see it); the
        part of it theta_hat and h integrate is at most ``limit`` (why: ``'late'`` beyond it).
        The first state integrates one ``period``.
        """
        if gap:
            self.t_used = max(self.t_used, t_state)
            return 0.0, 0.0, ''
        dt = self.state_dt(t_state, period)
        if dt == 0.0:
            return 0.0, 0.0, 'stale'
        self.t_used = t_state
        return dt, min(dt, limit), 'late' if dt > limit else ''

    def state_dt(self, t_state: float, period: float) -> float:
        """Return the time :meth:`state_step` would give without a gap (0: no new state)."""
        if t_state <= self.t_used:
            return 0.0
        return period if self.t_used == -math.inf else t_state - self.t_used
