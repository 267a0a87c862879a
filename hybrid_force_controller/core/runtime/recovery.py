"""
Fault episodes and the trusted estimate: what keeps theta_hat from running away (pure numpy).

A real loop meets stalls it does not make: a scheduler hiccup, a driver that drops
commands, a command watchdog that cuts the torque while the arm falls onto the workpiece.
What follows is a transient the model does not explain (an impact, a fall, a surface
pressed 40 N deep), and an adaptation law integrating it reads it as a model error:
theta_hat ran from [1.30, 0.90] to [3.37, 2.78] in under a second after a 202 ms stall.
:class:`Recovery` is the runtime's bookkeeping of such *episodes* (docs/design.md,
"Recovery from stalls and drops"):

* an episode begins on a stall the node sees in its own tick times, a restart (a
  re-activation: the arm moved under the held effort), a contact loss, safe mode, a force
  transient ``|f_n - f_d| > transient_force``, or a tracking error
  ``|e| > transient_error``, which is how an effort the plant did not apply shows in the
  arm's response (the arm falls while the law expects the commanded motion);
* while it lasts, theta_hat holds the *trusted* estimate: adaptation (26) is frozen;
* it ends after ``calm_time`` of calm: in contact, in the force loop, with
  ``|f_n - f_d| < calm_force`` and ``|e| < calm_error``; after :data:`SETTLE_AFTER_S`,
  ``calm_time`` *settled* is enough: the same with the errors below the thresholds that
  start an episode (a trusted estimate from a calm stretch of little excitation, the sine
  at rest at a turning point, can be wrong enough that calm never returns while it holds:
  adaptation stayed frozen for 13 s offline);
* the trusted estimate is a theta_hat that kept the loop calm, in contact, for ``calm_time``
  after it: each calm window of ``calm_time`` trusts the estimate it began with (the
  estimate at the window's end, trusted before, let a theta_hat thrown by a fault in one
  tick become the trusted one at the next, before the errors it causes had grown);
* before the first calm stretch there is nothing trusted, and the start-up is the transient
  adaptation is for: an episode then only counts, adaptation going on (its error
  saturated), unless the loop itself was broken for longer than the inputs may be old
  (:data:`LOOP_KINDS`: safe mode, a restart, a stall, which the runtime opens only when
  longer than ``state_timeout``) while in the force loop. Such an episode is *provisional*:
  theta_hat holds the estimate that held the tool on the surface up to then, until
  ``calm_time`` settled (at most
  :data:`SETTLE_AFTER_S`: it is a guess, nothing trusted backs it). Without it, three 300 ms
  hiccups of the whole machine in the first 2 s (sim and controller frozen together: the
  sim's catch-up drops the arm 2 cm into the surface each time) took theta_hat from
  [1.18, 0.79] to its projection bound, the tool lifted off, in 5 of 5 runs over DDS.

Time is an argument: the caller passes the tick's time; nothing here reads a clock.
"""
from __future__ import annotations

import math

import numpy as np

from ..config.groups import RecoveryConfig, RecoveryConfigError

__all__ = ['EPISODE_KINDS', 'LOOP_KINDS', 'Recovery', 'RecoveryConfig', 'RecoveryConfigError',
           'SETTLE_AFTER_S']

#: what starts an episode (the /diagnostics counters are ``episodes_<kind>``)
EPISODE_KINDS = ('stall', 'restart', 'contact_loss', 'safe_mode', 'force_transient',
                 'tracking_fault')
#: the loop itself broke (not the model): before trust, such an episode holds theta_hat
LOOP_KINDS = ('stall', 'restart', 'safe_mode')
SETTLE_AFTER_S = 5.0  # an episode this long ends once settled (not only calm), s


def _stretch(since: float, holds: bool, t: float) -> float:
    """Return the start of a stretch that ``holds`` at ``t`` (NaN when it does not)."""
    return (t if math.isnan(since) else since) if holds else math.nan


def _below(x: float, bound: float) -> bool:
    """Say whether ``x`` is below an episode threshold (0: that threshold is off)."""
    return bound <= 0.0 or x < bound


class Recovery:
    """
    Episodes, their counts and the trusted theta_hat of one runtime.

    ``p`` is the number of parameters. :meth:`begin` opens an episode and returns the
    estimate to hold; :meth:`note` takes each tick's errors, :meth:`triggered` says
    whether they start an episode at the next tick.
    """

    def __init__(self, p: int, cfg: RecoveryConfig) -> None:
        self.cfg = cfg
        self.counts = dict.fromkeys(EPISODE_KINDS, 0)
        self.episode = ''  # the kind of the episode under way ('' when none)
        self.t_begin = -math.inf
        self.has_trusted = False
        self.trusted = np.zeros(p)  # valid when has_trusted
        self.provisional = False  # the episode under way holds ``held`` (nothing trusted yet)
        self.held = np.zeros(p)  # what theta_hat holds during a frozen episode
        self._calm_since = math.nan  # start of the current calm stretch (NaN: not calm)
        self._settled_since = math.nan  # start of the current settled stretch
        self._in_loop = False  # the last tick was in the force loop
        self._window_since = math.nan  # start of the current calm window (trust)
        self._candidate = np.zeros(p)  # theta_hat at its start
        self._df = self._e = 0.0  # the last tick's |f_n - f_d| (N) and |e| (m/s)

    def configure(self, cfg: RecoveryConfig, theta_min: np.ndarray | None = None,
                  theta_max: np.ndarray | None = None) -> None:
        """
        Install a new configuration (a parameter set); the state is kept.

        The trusted estimate is clipped into new projection bounds ``theta_min``,
        ``theta_max`` (a set that moves them).
        """
        self.cfg = cfg
        if theta_min is not None and theta_max is not None:
            np.clip(self.trusted, theta_min, theta_max, out=self.trusted)

    @property
    def frozen(self) -> bool:
        """Say whether adaptation is frozen: an episode under way and an estimate to hold."""
        return bool(self.episode) and (self.has_trusted or self.provisional) and self.cfg.enabled

    def begin(self, kind: str, t: float, theta_hat: np.ndarray) -> np.ndarray | None:
        """
        Open an episode of ``kind`` at time ``t`` (one already under way goes on, counted once).

        ``theta_hat`` is the estimate now. Returns the estimate theta_hat must take: the
        trusted one; before there is one, ``theta_hat`` itself for a :data:`LOOP_KINDS`
        episode met in the force loop (provisional); None when adaptation goes on.
        """
        self._calm_since = self._settled_since = self._window_since = math.nan
        if not self.episode:
            self.episode, self.t_begin = kind, t
            self.counts[kind] += 1
        if self.has_trusted:
            np.copyto(self.held, self.trusted)
        elif kind in LOOP_KINDS and self._in_loop and not self.provisional:
            self.provisional = True  # also when a counting episode is under way
            self.t_begin = t
            np.copyto(self.held, theta_hat)
        return self.held if self.frozen else None

    def triggered(self) -> str:
        """Return the kind of episode the last tick's errors start ('' for none)."""
        cfg = self.cfg
        if 0.0 < cfg.transient_force < self._df:
            return 'force_transient'
        if 0.0 < cfg.transient_error < self._e:
            return 'tracking_fault'
        return ''

    def note(self, t: float, df: float, e: float, in_force_loop: bool,
             theta_hat: np.ndarray) -> bool:
        """
        Note one tick at time ``t``; return True when an episode ended at it.

        ``df = |f_n - f_d|`` (N), ``e = |e|`` (m/s); calm is ``in_force_loop`` (in
        contact, running) with both below their calm bounds, settled the same below the
        episode thresholds. ``calm_time`` of calm ends the episode under way (of settled: a
        provisional one, or one older than SETTLE_AFTER_S; a provisional one ends at
        SETTLE_AFTER_S in any case); with none, calm windows make estimates trusted.
        """
        self._df, self._e, self._in_loop = df, e, in_force_loop
        cfg = self.cfg
        calm = in_force_loop and df < cfg.calm_force and e < cfg.calm_error
        settled = (in_force_loop and _below(df, cfg.transient_force)
                   and _below(e, cfg.transient_error))
        self._calm_since = _stretch(self._calm_since, calm, t)
        self._settled_since = _stretch(self._settled_since, settled, t)
        if self.episode:
            long = t - self.t_begin >= SETTLE_AFTER_S
            since = self._settled_since if self.provisional or long else self._calm_since
            if not (t - since >= cfg.calm_time  # NaN: not calm (or settled) now
                    or (self.provisional and long)):
                return False
            self.episode, self.provisional = '', False
            return True
        self._trust(t, calm, theta_hat)
        return False

    def _trust(self, t: float, calm: bool, theta_hat: np.ndarray) -> None:
        """Trust the estimate a calm window began with once it has lasted ``calm_time``."""
        if not calm:
            self._window_since = math.nan
            return
        if not math.isnan(self._window_since):
            if t - self._window_since < self.cfg.calm_time:
                return
            np.copyto(self.trusted, self._candidate)
            self.has_trusted = True
        self._window_since = t
        np.copyto(self._candidate, theta_hat)
