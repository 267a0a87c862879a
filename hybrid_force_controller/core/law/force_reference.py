"""
The desired normal force f_d(t): a new value is approached at a bounded rate (pure Python).

The law's error (11) holds ``c fdot_d`` in r and ``lambda1 c fdot_d`` in rdot
(control_law.py), so a ramped f_d is fed forward; a step (``rate`` 0) has no rate to feed.
A new f_d comes from the ``f_d`` parameter or ``~/target_wrench``; the paper's f_d is constant,
so its reproduction never ramps. Times are arguments.
"""
from __future__ import annotations

__all__ = ['ForceRamp']


class ForceRamp:
    """``f_d`` moving toward ``target`` at ``rate`` N/s (0: at once)."""

    def __init__(self, f_d: float, rate: float) -> None:
        self.value = self.target = float(f_d)
        self.rate = rate
        self.fdot = 0.0  # the rate of the last step, N/s

    def configure(self, target: float, rate: float) -> None:
        """Take a new target and rate; with rate 0 the value jumps to the target."""
        self.target, self.rate = float(target), rate
        if rate <= 0.0:
            self.value, self.fdot = self.target, 0.0

    def step(self, dt: float) -> float:
        """
        Advance ``dt`` s (>= 0) toward the target; return f_d.

        ``fdot`` is the rate over this step (0 once the target is reached; a step with dt 0,
        a tick without a new state, keeps the last rate).
        """
        gap = self.target - self.value
        if gap == 0.0:
            self.fdot = 0.0
            return self.value
        if dt <= 0.0:
            return self.value
        limit = self.rate * dt
        if abs(gap) <= limit:
            self.value, self.fdot = self.target, 0.0
        else:
            self.value += limit if gap > 0.0 else -limit
            self.fdot = self.rate if gap > 0.0 else -self.rate
        return self.value
