"""
Timing of the control loop as the node sees it: input-to-command delay and command rate.

:class:`DelayStats` keeps a ring buffer of delays (preallocated; one store per command) and
gives p50/p99/max over the last ``size`` commands; :class:`RateMeter` turns a running count
into a rate between two reports; :class:`GapMeter` the gaps between events (the efforts a
plant receives, the states it publishes) into their p99 and max between two reports.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['DelayStats', 'GapMeter', 'RateMeter']


class DelayStats:
    """Ring buffer of delays, seconds in, milliseconds out."""

    def __init__(self, size: int = 4096) -> None:
        self._buf = np.full(size, np.nan)
        self._k = 0

    def record(self, delay_s: float) -> None:
        self._buf[self._k % self._buf.size] = delay_s
        self._k += 1

    def summary(self, prefix: str = 'delay') -> dict[str, float]:
        """``{prefix}_p50_ms``, ``_p99_ms``, ``_max_ms`` (NaN without samples)."""
        n = min(self._k, self._buf.size)
        if n == 0:
            nan = float('nan')
            return {f'{prefix}_p50_ms': nan, f'{prefix}_p99_ms': nan, f'{prefix}_max_ms': nan}
        d = self._buf[:n] * 1e3
        return {f'{prefix}_p50_ms': float(np.percentile(d, 50)),
                f'{prefix}_p99_ms': float(np.percentile(d, 99)),
                f'{prefix}_max_ms': float(d.max())}


class RateMeter:
    """Events per second between two calls of :meth:`rate`."""

    def __init__(self) -> None:
        self.count = 0
        self._count0, self._t0 = 0, None

    def rate(self, t: float) -> float:
        """Rate since the previous call (NaN on the first); ``t`` in seconds, any clock."""
        t0, c0 = self._t0, self._count0
        self._t0, self._count0 = t, self.count
        if t0 is None or t <= t0:
            return float('nan')
        return (self.count - c0) / (t - t0)


class GapMeter:
    """Gaps between consecutive events, summarised and forgotten at each :meth:`take`."""

    def __init__(self, size: int = 8192) -> None:
        self._buf = np.zeros(size)
        self._k = 0
        self._t_last: float | None = None

    def mark(self, t: float) -> None:
        """One event at ``t`` (s, a monotonic clock)."""
        if self._t_last is not None and self._k < self._buf.size:
            self._buf[self._k] = t - self._t_last
            self._k += 1
        self._t_last = t

    def take(self, prefix: str) -> dict[str, float]:
        """Return the p99 and max gap since the last take, ms (``{prefix}_p99_ms``, NaN: none)."""
        gaps, self._k = self._buf[:self._k] * 1e3, 0
        if gaps.size == 0:
            return {f'{prefix}_p99_ms': math.nan, f'{prefix}_max_ms': math.nan}
        return {f'{prefix}_p99_ms': float(np.percentile(gaps, 99)),
                f'{prefix}_max_ms': float(gaps.max())}
