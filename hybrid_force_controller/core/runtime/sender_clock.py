"""
A sender's clock against the controller's: stamps checked and mapped onto the controller's clock.

One :class:`SenderClock` per input stream (joint states, wrench). Each message brings its stamp
``t_stamp`` (the sender's clock) and ``t_recv``, the controller's clock when it arrived (an
argument: the core never reads a clock). Their difference, the skew ``t_stamp - t_recv``, is
the sender's clock offset less the transport delay.

* ``|skew| > max_clock_skew``: the stamp cannot be from a clock the controller should trust
  (an hour ahead: a replayed or corrupted message, a PC whose clock was never set). Refused
  with the reason, never learned from.
* The offset ``d_hat`` is learned from the first message and then tracked slowly: each
  message moves it towards its skew by at most ``RATE_UP`` (up) or ``RATE_DOWN`` (down) times
  the time since the previous message. So it sits near the upper edge of the skews (about
  the 90th percentile: the offset less the fastest transport), follows a clock that drifts
  (up to 2000 ppm faster, 200 ppm slower than the controller's), and a single message moves it
  by at most 2 us per ms. In the first ``LEARN_S`` of a stream it rises at ``LEARN_RATE_UP``,
  so a slow first message is forgotten within a fraction of a second.
* The runtime sees ``t = min(t_stamp - d_hat, t_recv + lead)``: time differences come from
  the stamps (exact to 0.2 %), staleness is measured on the controller's clock, and no sample
  is dated more than ``lead`` (the runtime uses half a control period) after it arrived: the
  loop's clock never runs ahead of itself, even while a slow first message is forgotten. A
  sensor 2 s ahead or behind for a whole run just works.
* A skew further than ``tolerance`` (the runtime uses ``state_timeout``) from ``d_hat`` is a
  jump of the sender's clock or a stray message: refused, so it never becomes the last
  sample later ones are compared against. A message that late is stale on arrival anyway;
  one that early cannot be.
* Recovery: when refused messages keep agreeing with each other (within ``tolerance``) on a
  new skew for ``relearn_after`` (the runtime uses 2 ``state_timeout``) with no accepted
  message between them, the sender's clock really moved (an NTP step): the stream learns the
  new offset and goes on, so nothing locks the stream out for longer than that.
* A relearned sample is dated when it arrived, but never before the last date the stream gave:
  that one may be dated up to ``lead`` after its arrival, and a relearn in a burst comes
  microseconds later; dated earlier, the runtime dropped it as older than the last one (s58g,
  docs/results.md section 40).
* In the first ``LEARN_S`` two refused messages in a row that agree are enough: the offset was
  learned from the first message, which may have been the stray one. Fast DDS's first send to
  a reader that just joined can sleep up to 333 ms, so a stream's first sample can come that
  late, and every sample after it then looks early by as much. One CI run refused 217 and 218
  samples of the two streams of a clean cell: what a reference off by more than 0.1 s, relearned
  after 0.2 s at 1 kHz, gives (s50d, docs/results.md section 28; its cause was not observed).
  In the first second that now costs one refused message. A stray message between good ones
  is still refused and never learned (the good one after it breaks the agreement).
* The jumps refused in a stream's first ``LEARN_S`` (since it was learned, or learned anew)
  are counted apart (``startup_refusals``): the middleware's start-up, not the sender's clock.
  While the cell's participants meet, one first send can sleep 333 ms under a lock that the
  sender's writers share: that stream's first sample comes late, and the other stream's
  sample held up behind it comes 0.33 s later than its predecessors (s52b, docs/results.md
  section 29).
"""
from __future__ import annotations

import math

from .inputs import InputError

__all__ = ['ImplausibleStamp', 'LEARN_RATE_UP', 'LEARN_S', 'RATE_DOWN', 'RATE_UP',
           'SenderClock']

RATE_UP = 2e-3        # d_hat rises at most this many s per s between messages
RATE_DOWN = 2e-4      # and falls at most this many (the upper edge of the skews)
LEARN_RATE_UP = 0.1   # in the first LEARN_S of a stream: a slow first message is forgotten
LEARN_S = 1.0


class ImplausibleStamp(InputError):
    """A stamp too far from the controller's clock, or from its sender's learned offset."""


def _side(dt: float) -> str:
    return 'ahead of' if dt > 0.0 else 'behind'


class SenderClock:
    """One stream's clock offset, checks and mapping (see the module docstring)."""

    def __init__(self, stream: str, max_skew: float = 10.0, tolerance: float = 0.1,
                 relearn_after: float = 0.2, lead: float = 5e-4) -> None:
        self.stream = stream  # names the stream in the reasons ('wrench', 'joint state')
        self.configure(max_skew, tolerance, relearn_after, lead)
        self.relearns = 0  # offsets learned anew (not the first)
        self.startup_refusals = 0  # jumps refused in the first LEARN_S since a (re)learn
        self.reset()

    def configure(self, max_skew: float, tolerance: float, relearn_after: float,
                  lead: float) -> None:
        """Set the bounds, s (``max_skew`` 0: stamps are passed through unchecked)."""
        self.max_skew, self.tolerance, self.relearn_after = max_skew, tolerance, relearn_after
        self.lead = lead

    def reset(self) -> None:
        """Forget the offset (the next message is learned from)."""
        self.offset: float | None = None  # d_hat, s: sender's clock minus the controller's
        self._t_first = self._t_last = -math.inf  # reception of the first and last message
        self._t_out = -math.inf  # the last date given (a relearned sample is never older)
        self._cand: float | None = None  # the skew refused messages agree on, since when
        self._cand_since = 0.0

    def receive(self, t_stamp: float, t_recv: float) -> float:
        """Return the stamp on the controller's clock, or raise :class:`ImplausibleStamp`."""
        if not self.max_skew:
            return t_stamp
        skew = t_stamp - t_recv
        if not abs(skew) <= self.max_skew:  # (NaN too)
            raise ImplausibleStamp(
                f'{self.stream} stamp is {abs(skew):.4g} s {_side(skew)} the controller'
                f"'s clock (max_clock_skew {self.max_skew:g} s)")
        d = self.offset
        if d is None:
            return self._learn(skew, t_recv)
        dev = skew - d
        if abs(dev) > self.tolerance:
            if self._agreed(skew, t_recv):
                self.relearns += 1
                return self._learn(skew, t_recv, not_before=self._t_out)
            self.startup_refusals += t_recv - self._t_first < LEARN_S
            raise ImplausibleStamp(
                f'{self.stream} stamp jumps {abs(dev):.4g} s {_side(dev)} its sender'
                f"'s clock (offset {d:+.4g} s; more than state_timeout {self.tolerance:g} s)")
        self._cand = None
        gap = t_recv - self._t_last
        gap = 0.0 if gap < 0.0 else gap if gap < self.tolerance else self.tolerance
        if dev > 0.0:
            rate = LEARN_RATE_UP if t_recv - self._t_first < LEARN_S else RATE_UP
            d += min(dev, rate * gap)
        else:
            d -= min(-dev, RATE_DOWN * gap)
        self.offset, self._t_last = d, t_recv
        t, t_max = t_stamp - d, t_recv + self.lead
        self._t_out = t if t < t_max else t_max
        return self._t_out

    def _learn(self, skew: float, t_recv: float, not_before: float = -math.inf) -> float:
        """Learn ``skew``; date the sample when it came, never before ``not_before``."""
        self.offset, self._cand = skew, None
        self._t_first = self._t_last = t_recv
        self._t_out = t_recv if t_recv > not_before else not_before
        return self._t_out

    def _agreed(self, skew: float, t_recv: float) -> bool:
        """
        Say whether refused messages agreed on ``skew`` for ``relearn_after``; note it.

        In the stream's first ``LEARN_S``, two in a row that agree are enough.
        """
        if self._cand is None or abs(skew - self._cand) > self.tolerance:
            self._cand, self._cand_since = skew, t_recv
            return False
        return (t_recv - self._t_first < LEARN_S
                or t_recv - self._cand_since >= self.relearn_after)
