"""
Figures of one recovery from a stall (pure numpy): how fast, how calm, how far theta_hat moved.

The same definitions serve the offline tests (test_stalls.py), the real-time DDS tests and
``bench --ros --freezes`` (issue 16's targets), so the figures in docs/results.md and the
assertions measure one thing:

* ``back_s``: time from the release (SIGCONT, or the end of a modelled stall) to the start
  of the first stretch of ``hold_s`` in which the true normal force stays within ``tol`` of
  ``f_d`` (NaN if none);
* ``theta_change``: the largest relative change of any component of theta_hat over
  ``window_s`` after the release, against its value just before the freeze;
* ``rms_force_error_n``: RMS of ``f - f_d`` over ``[rms_from_s, window_s]`` after the release;
* ``peak_force_n``: the largest true force from the freeze to the end of the window (the
  impact of an arm that fell while its torque was off: physics, reported).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['first_hold', 'recovery_figures', 'settle_time', 'theta_steady']


def first_hold(t: np.ndarray, ok: np.ndarray, t0: float, hold_s: float = 0.2) -> float:
    """
    Return the time after ``t0`` at which ``ok`` starts to hold for ``hold_s``, s.

    ``t`` are the sample times (s, increasing) of the flags ``ok``; NaN if it never does.
    """
    after = t >= t0
    start = math.nan
    for ti, good in zip(t[after], ok[after]):
        if not good:
            start = math.nan
        elif math.isnan(start):
            start = ti
        if not math.isnan(start) and ti - start >= hold_s:
            return float(start - t0)
    return math.nan


def settle_time(t: np.ndarray, f: np.ndarray, t0: float, f_d: float, tol: float = 0.1,
                hold_s: float = 0.2) -> float:
    """
    Return the time after ``t0`` at which ``|f - f_d| <= tol`` starts to hold ``hold_s``, s.

    ``t`` are the sample times (s, increasing) of the forces ``f`` (N); NaN if it never does.
    """
    return first_hold(t, np.abs(f - f_d) <= tol, t0, hold_s)


def theta_steady(t: np.ndarray, theta: np.ndarray, span_s: float = 2.0,
                 tol: float = 0.01) -> bool:
    """
    Say whether theta_hat moved less than ``tol`` (relative) over its last ``span_s``.

    ``t`` (s, increasing) and ``theta`` (rows): False while they cover less than ``span_s``.
    A freeze is measured against a learned theta_hat only (its change is the figure).
    """
    t, theta = np.asarray(t, dtype=float), np.asarray(theta, dtype=float)
    if t.size < 10 or t[-1] - t[0] < span_s:
        return False
    recent = theta[t >= t[-1] - span_s]
    return bool(np.all(np.ptp(recent, axis=0) <= tol * np.abs(recent[-1])))


def recovery_figures(t: np.ndarray, f: np.ndarray, t_freeze: float, t_release: float,
                     f_d: float, t_theta: np.ndarray | None = None,
                     theta: np.ndarray | None = None, window_s: float = 6.0,
                     rms_from_s: float = 2.0, tol: float = 0.1,
                     hold_s: float = 0.2) -> dict[str, float]:
    """
    Return the figures of the module docstring for one freeze.

    ``t``, ``f``: times (s) and true normal forces (N); ``t_theta``, ``theta``: times and
    theta_hat rows (optional: ``theta_change`` is NaN without them).
    """
    t, f = np.asarray(t, dtype=float), np.asarray(f, dtype=float)
    win = (t >= t_freeze) & (t <= t_release + window_s)
    rms = (t >= t_release + rms_from_s) & (t <= t_release + window_s)
    out = {'back_s': settle_time(t, f, t_release, f_d, tol, hold_s),
           'peak_force_n': float(f[win].max()) if win.any() else math.nan,
           'rms_force_error_n': (float(np.sqrt(np.mean((f[rms] - f_d) ** 2)))
                                 if rms.any() else math.nan),
           'theta_change': math.nan}
    if t_theta is not None and theta is not None and len(t_theta):
        t_theta, theta = np.asarray(t_theta, dtype=float), np.asarray(theta, dtype=float)
        before = np.flatnonzero(t_theta < t_freeze)
        after = (t_theta >= t_release) & (t_theta <= t_release + window_s)
        if before.size and after.any():
            ref = theta[before[-1]]
            out['theta_change'] = float(np.max(np.abs(theta[after] / ref - 1.0)))
    return out
