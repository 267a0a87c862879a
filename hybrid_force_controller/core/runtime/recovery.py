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
  ``|f_n - f_d| < calm_force`` and ``|e| < calm_error``;
* the trusted estimate is theta_hat of the last calm stretch in contact, updated on every
  tick once calm has lasted ``calm_time``. Before the first calm stretch there is none:
  the start-up is the transient adaptation is for, and nothing better is known, so an
  episode then only counts (adaptation goes on, its error saturated as before).

Time is an argument: the caller passes the tick's time; nothing here reads a clock.
"""
from __future__ import annotations

import math

import numpy as np

from ..config.groups import RecoveryConfig, RecoveryConfigError

__all__ = ['EPISODE_KINDS', 'Recovery', 'RecoveryConfig', 'RecoveryConfigError']

#: what starts an episode (the /diagnostics counters are ``episodes_<kind>``)
EPISODE_KINDS = ('stall', 'restart', 'contact_loss', 'safe_mode', 'force_transient',
                 'tracking_fault')


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
        self._calm_since = math.nan  # start of the current calm stretch (NaN: not calm)
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
        """Say whether adaptation is frozen: an episode under way and a trusted estimate."""
        return bool(self.episode) and self.has_trusted and self.cfg.enabled

    def begin(self, kind: str, t: float) -> np.ndarray | None:
        """
        Open an episode of ``kind`` at time ``t`` (one already under way goes on, counted once).

        Returns the trusted estimate theta_hat must take now, or None (nothing to restore:
        no trusted estimate yet, or recovery disabled).
        """
        self._calm_since = math.nan
        if not self.episode:
            self.episode, self.t_begin = kind, t
            self.counts[kind] += 1
        return self.trusted if self.frozen else None

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
        contact, running) with both below their calm bounds. A calm stretch of
        ``calm_time`` ends the episode under way, or (with none) makes ``theta_hat`` the
        trusted estimate.
        """
        self._df, self._e = df, e
        cfg = self.cfg
        if not (in_force_loop and df < cfg.calm_force and e < cfg.calm_error):
            self._calm_since = math.nan
            return False
        if math.isnan(self._calm_since):
            self._calm_since = t
        if t - self._calm_since < cfg.calm_time:
            return False
        if self.episode:
            self.episode = ''
            return True
        np.copyto(self.trusted, theta_hat)
        self.has_trusted = True
        return False
