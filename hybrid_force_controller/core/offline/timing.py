"""
Timing model of a real-time loop between two processes over DDS (for engine.py).

A :class:`TimingModel` says how late things happen: one-way message latency (a fixed part
plus an exponential extra), controller compute time, timer lateness, and stalls of either
process (random, Poisson with log-uniform durations, or scheduled, e.g. SIGSTOP for 30 ms).
:class:`Schedule` draws one realisation from a seed, in integer nanoseconds. Pure numpy.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Iterator

import numpy as np

__all__ = ['Schedule', 'Stall', 'TimingError', 'TimingModel']


class TimingError(ValueError):
    """An inconsistent timing model (negative times, a period of zero ...)."""


@dataclass(frozen=True)
class Stall:
    """Process ``who`` ('controller' or 'plant') runs nothing during [t, t + duration), s."""

    who: str
    t: float
    duration: float


@dataclass(frozen=True)
class TimingModel:
    """
    Delays and gaps of the loop; the defaults are ideal (no latency, no stalls).

    Attributes
    ----------
    period : plant step and controller timer period, s.
    latency, latency_jitter : one-way latency of every message, fixed part and mean of an
        exponential extra, s (the same in both directions).
    delay_steps : extra sensor-to-actuation delay in whole periods (the lockstep model).
    compute : controller compute time per tick, s (its command leaves after it).
    tick_on_state : tick on each new state (plus a watchdog) instead of a free timer.
    tick_phase, tick_jitter : timer offset from the plant's steps and mean exponential
        lateness of each timer tick, s.
    stall_rate_hz, stall_s : random stalls of each process: Poisson rate, and the range of
        their log-uniform durations, s.
    stalls : scheduled stalls.
    seed : seed of every random draw.
    drain_per_ms : how the states sent during a stall of the controller reach it: at this
        many per ms after the stall, oldest first, the newer ones queued behind them (a
        socket's backlog that the middleware's thread drains; over DDS the first state after
        a 300 ms freeze was 300 ms old, and the inputs were 100 ms old again about 100 ms
        later: about 3 per ms). ``inf``: only the newest, at the stall's end.

    """

    period: float = 1e-3
    latency: float = 0.0
    latency_jitter: float = 0.0
    delay_steps: int = 0
    compute: float = 0.0
    tick_on_state: bool = False
    tick_phase: float = 0.0
    tick_jitter: float = 0.0
    stall_rate_hz: float = 0.0
    stall_s: tuple[float, float] = (1e-3, 30e-3)
    stalls: tuple[Stall, ...] = ()
    seed: int = 0
    drain_per_ms: float = math.inf

    def __post_init__(self) -> None:
        values = (self.latency, self.latency_jitter, self.compute, self.tick_phase,
                  self.tick_jitter, self.stall_rate_hz, *self.stall_s)
        if not (self.period > 0.0 and all(math.isfinite(v) and v >= 0.0 for v in values)
                and self.delay_steps >= 0 and 0.0 < self.stall_s[0] <= self.stall_s[1]
                and self.drain_per_ms > 0.0):
            raise TimingError(f'invalid timing model: {self}')
        if any(s.who not in ('controller', 'plant') or s.duration < 0 for s in self.stalls):
            raise TimingError(f'invalid stalls: {self.stalls}')

    @classmethod
    def lockstep(cls, delay_steps: int = 0) -> 'TimingModel':
        """Model a controller that sees the state of ``delay_steps`` periods ago, no jitter."""
        return cls(delay_steps=delay_steps)

    @classmethod
    def ros_measured(cls, seed: int = 0, **overrides: Any) -> 'TimingModel':
        """
        Model two rclpy processes on this 2-core machine (docs/results.md).

        0.1-0.4 ms per message, 0.2 ms compute, timer lateness, and stalls of 1-30 ms a few times a
        second in each process (scheduler, garbage collector, other load).
        """
        base = {'latency': 1e-4, 'latency_jitter': 1e-4, 'compute': 2e-4, 'tick_phase': 5e-4,
                'tick_jitter': 1e-4, 'stall_rate_hz': 4.0, 'stall_s': (1e-3, 30e-3),
                'seed': seed}
        return cls(**{**base, **overrides})


def _to_ns(t: float) -> int:
    return int(round(t * 1e9))


@dataclass
class Schedule:
    """One seeded realisation of a timing model over ``duration`` seconds (times in ns)."""

    model: TimingModel
    duration: float
    period_ns: int = field(init=False)

    def __post_init__(self) -> None:
        m = self.model
        self.period_ns = _to_ns(m.period)
        self._compute_ns = _to_ns(m.compute)
        self._latency_ns = None if m.latency_jitter else _to_ns(m.latency)  # None: drawn
        self._rng = [np.random.default_rng([m.seed, i]) for i in range(4)]
        self._stalls = {who: self._draw_stalls(who, i) for i, who in
                        enumerate(('controller', 'plant'))}
        self._next_tick = _to_ns(m.tick_phase)
        self._last_tick = -1
        self._busy_until = -1
        self._pending: int | None = None
        self._drained: dict[int, int] = {}  # a controller stall's end -> states queued at it

    def _draw_stalls(self, who: str, stream: int) -> list[tuple[int, int]]:
        m = self.model
        rng = np.random.default_rng([m.seed, 10 + stream])
        out = [(_to_ns(s.t), _to_ns(s.t + s.duration)) for s in m.stalls if s.who == who]
        if m.stall_rate_hz > 0.0:
            n = rng.poisson(m.stall_rate_hz * self.duration)
            starts = rng.uniform(0.0, self.duration, n)
            lo, hi = np.log(m.stall_s[0]), np.log(m.stall_s[1])
            lengths = np.exp(rng.uniform(lo, hi, n))
            out += [(_to_ns(a), _to_ns(a + d)) for a, d in zip(starts, lengths)]
        return sorted(out)

    def _stall_end(self, who: str, t: int) -> int | None:
        """End of the stall of ``who`` that covers ``t`` (None if it runs at ``t``)."""
        end = None
        for a, b in self._stalls[who]:
            if a > t:
                break
            if t < b:
                end = b if end is None else max(end, b)
        return end

    def plant_stalled(self, t: int) -> bool:
        return self._stall_end('plant', t) is not None

    def _latency(self, stream: int) -> int:
        if self._latency_ns is not None:
            return self._latency_ns
        m = self.model
        return _to_ns(m.latency + self._rng[stream].exponential(m.latency_jitter))

    def state_arrival(self, t_pub: int) -> int:
        """When a state published at ``t_pub`` is read by the controller."""
        t = t_pub + self._latency(0) + self.model.delay_steps * self.period_ns
        end = self._stall_end('controller', t)
        if end is None or not math.isfinite(self.model.drain_per_ms):
            return t if end is None else end
        k = self._drained[end] = self._drained.get(end, -1) + 1  # the k-th of its backlog
        return end + _to_ns(k * 1e-3 / self.model.drain_per_ms)

    def command_arrival(self, t_tick: int) -> int:
        """When a command computed at ``t_tick`` reaches the plant."""
        return t_tick + self._compute_ns + self._latency(1)

    def ticks_until(self, t: int, inbox: Any) -> Iterator[int]:
        """Return the controller tick times in (last tick, t], in order, as they come (lazily)."""
        return self._event_ticks(t, inbox) if self.model.tick_on_state else self._timer_ticks(t)

    def _start_time(self, want: int) -> int:
        """
        Return the start of a tick wanted at ``want``.

        It starts when the controller is neither stalled nor busy.
        """
        t = max(want, self._busy_until, self._last_tick + 1)
        end = self._stall_end('controller', t)
        return t if end is None else end

    def _commit(self, start: int) -> int:
        self._last_tick = start
        self._busy_until = start + self._compute_ns
        return start

    def _timer_ticks(self, t: int) -> Iterator[int]:
        m, P = self.model, self.period_ns
        while True:
            if self._pending is None:
                late = _to_ns(self._rng[2].exponential(m.tick_jitter)) if m.tick_jitter else 0
                self._pending = self._next_tick + late
            start = self._start_time(self._pending)
            if start > t:
                return
            self._pending = None
            while self._next_tick <= start:  # periods missed while stalled are skipped
                self._next_tick += P
            yield self._commit(start)

    def _event_ticks(self, t: int, inbox: Any) -> Iterator[int]:
        """One tick per arrived state; a watchdog tick after 2 periods without one."""
        while True:
            arrivals = [a for a, _ in inbox.queue if a > self._last_tick]
            want = arrivals[0] if arrivals else self._last_tick + 2 * self.period_ns
            start = self._start_time(want)
            if start > t:
                return
            yield self._commit(start)
