"""Loop timing statistics of a periodic callback (pure numpy; times come from the caller)."""
from __future__ import annotations

import math

import numpy as np

__all__ = ['HoldStats', 'LoopStats', 'hold_phases']


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


class HoldStats:
    """
    How long each kind of callback held a thread: count, max and p99.9, since :meth:`reset`.

    A fixed histogram per kind (``BIN_S`` wide bins up to ``N_BINS * BIN_S``, the last bin
    holds everything longer) and an exact maximum, so :meth:`record` costs a list store
    and a compare whatever the run's length, and :meth:`summary` covers the whole run.
    """

    BIN_S = 1e-5
    N_BINS = 10000
    _MIDDLES = np.arange(N_BINS) + 0.5  # each bin's middle, in bins

    def __init__(self, kinds: tuple[str, ...]) -> None:
        self.kinds = kinds
        self.reset()

    PHASES = ('inputs', 'tick', 'publish')  # of a joint-state callback (control_loop.py)

    def reset(self) -> None:
        """Forget every sample (a new activation)."""
        self._hist = {k: [0] * self.N_BINS for k in self.kinds}
        self._max = dict.fromkeys(self.kinds, 0.0)
        # the longest hold of all: (seconds, kind, seconds in each of PHASES or ())
        self.longest: tuple[float, str, tuple[float, ...]] = (0.0, '', ())

    def where(self) -> str:
        """
        Say where the longest hold went.

        E.g. ``joint_states 3.10 ms: inputs 0.05, tick 2.90, publish 0.15`` (ms each).

        Empty before any sample. Phases are given for joint-state callbacks and for timer
        callbacks that ticked (:func:`hold_phases`).
        """
        duration, kind, phases = self.longest
        if not kind:
            return ''
        text = f'{kind} {duration * 1e3:.2f} ms'
        if phases:
            text += ': ' + ', '.join(f'{name} {t * 1e3:.2f}'
                                     for name, t in zip(self.PHASES, phases))
        return text

    def record(self, kind: str, duration_s: float) -> None:
        """One callback of ``kind`` that held the thread ``duration_s``."""
        i = int(duration_s * 1e5)
        self._hist[kind][i if i < self.N_BINS else self.N_BINS - 1] += 1
        if duration_s > self._max[kind]:
            self._max[kind] = duration_s

    def summary(self) -> dict[str, float]:
        """
        Return ``{kind}_count``, ``_max_ms``, ``_p999_ms``, ``_mean_ms`` and the same for ``all``.

        p99.9 is the upper edge of the bin that holds it, the mean is over the bins' middles
        (within ``BIN_S``; what a kind costs the thread: count times mean), NaN without
        samples.
        """
        out: dict[str, float] = {}
        hists = {k: np.array(h) for k, h in self._hist.items()}
        maxima = dict(self._max)
        hists['all'] = sum(hists.values())
        maxima['all'] = max(maxima.values(), default=0.0)
        for kind, h in hists.items():
            count = int(h.sum())
            p999 = mean = math.nan
            if count:
                p999 = min((int(np.searchsorted(np.cumsum(h), 0.999 * count)) + 1)
                           * self.BIN_S, maxima[kind]) * 1e3
                mean = float(h @ self._MIDDLES) / count * self.BIN_S * 1e3
            out.update({f'{kind}_count': float(count), f'{kind}_max_ms': maxima[kind] * 1e3,
                        f'{kind}_p999_ms': p999, f'{kind}_mean_ms': mean})
        return out


def hold_phases(kind: str, t0: float, marks: tuple[float, float] | list[float],
                t1: float) -> tuple[float, ...]:
    """
    Split a hold from ``t0`` to ``t1`` into :attr:`HoldStats.PHASES`, s.

    ``marks`` are the times the inputs were decoded and the tick was done, both set to ``t0``
    when the callback began. A joint-state callback has them; a timer callback only when it
    ticked (``marks[1] > t0``: its inputs phase is then the hand-overs); any other: ``()``.
    """
    if kind == 'joint_states' or (kind == 'timer' and marks[1] > t0):
        return (marks[0] - t0, marks[1] - marks[0], t1 - marks[1])
    return ()
