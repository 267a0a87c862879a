"""Loop timing statistics of a periodic callback (pure numpy; times come from the caller)."""
from __future__ import annotations

import numpy as np

__all__ = ['LoopStats']


class LoopStats:
    """
    Ring buffer of callback start times and compute durations, seconds.

    ``record(t_start, t_end)`` once per callback with any monotonic clock; ``summary()``
    gives the period and compute-time percentiles over the last ``size`` callbacks.
    """

    def __init__(self, size: int = 4096) -> None:
        self._start = np.full(size, np.nan)
        self._compute = np.full(size, np.nan)
        self._k = 0

    def record(self, t_start: float, t_end: float) -> None:
        """One callback that started at ``t_start`` and returned at ``t_end``."""
        i = self._k % self._start.size
        self._start[i], self._compute[i] = t_start, t_end - t_start
        self._k += 1

    def summary(self) -> dict[str, float]:
        """
        Return the rate and the period and compute-time percentiles.

        Keys ``rate_hz``, ``period_p50_ms``, ``period_p99_ms``, ``compute_p50_ms``,
        ``compute_p99_ms`` and ``samples`` (NaN where there is too little data).
        """
        n = min(self._k, self._start.size)
        if n < 3:
            nan = float('nan')
            return {'rate_hz': nan, 'period_p50_ms': nan, 'period_p99_ms': nan,
                    'compute_p50_ms': nan, 'compute_p99_ms': nan, 'samples': float(n)}
        order = np.arange(self._k - n, self._k) % self._start.size
        start, compute = self._start[order], self._compute[order]
        period = np.diff(start)
        return {'rate_hz': float((n - 1) / (start[-1] - start[0])),
                'period_p50_ms': float(np.percentile(period, 50) * 1e3),
                'period_p99_ms': float(np.percentile(period, 99) * 1e3),
                'compute_p50_ms': float(np.percentile(compute, 50) * 1e3),
                'compute_p99_ms': float(np.percentile(compute, 99) * 1e3),
                'samples': float(n)}
