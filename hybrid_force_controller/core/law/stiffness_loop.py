"""
The online stiffness estimate in the runtime: the controller learns the surface (issue 13).

:class:`StiffnessLoop` is what :class:`~.runtime.ControllerRuntime` runs on every new joint
state after the control law: it feeds the estimator (stiffness.py, (S0)-(S8)) with the
filtered normal force ``f_n = n^T f``, the tool position ``x_n = n^T x`` of that state, the
state's dt and the contact state, and (``stiffness_estimation`` on) sets the law's k_s to
the rate-limited command (S7) through the O(1) ``set_k_s`` (control_law.py: ``c = 1/k_s``,
``lambda2 = lambda2_0 k_s0 / k_s``, ``lambda2 h`` continuous). The k_s of one state acts
from the next tick on. Pure Python + numpy; times are arguments.

A contact loss (the contact detector's falling edge) and a change of the surface under
the tool (S9) make the surface unknown again: the fit restarts from the prior, k_hat is
reported NaN until valid again, and k_s jumps to ``max(k_s, k_s0)`` (the configured k_s,
for which the delay margin was checked against any k <= k_max; a lower loop gain), then
falls again only to a new valid estimate. Parameter sets keep the estimate unless its
prior, bounds or the normal change (:meth:`StiffnessLoop.configure`).
"""
from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np

from .control_law import HybridForceController
from .stiffness import StiffnessConfig, StiffnessEstimator
from .stiffness_compiled import CompiledStiffnessEstimator

__all__ = ['StiffnessLoop', 'StiffnessStatus']


class StiffnessStatus(NamedTuple):
    """What /diagnostics and the report need (N/m unless stated)."""

    enabled: bool         # stiffness_estimation: the law uses the estimate
    k_hat: float          # the estimate, NaN until it has been valid once (unknown)
    k_hat_std: float      # its standard deviation (S6)
    valid: bool           # (S6): k_s may fall to it
    k_s: float            # k_s the law uses now
    lambda2: float        # lambda2 the law uses now, m/(N s^2)
    near_k_max: bool      # (S8) on a known or saturated estimate (not the prior): WARN
    saturated: bool       # held at k_min or k_max by the projection
    samples_used: int     # exciting samples (S5) since the start
    samples_rejected: int  # non-finite samples and jumps of x_n (S10)
    contacts: int         # contact episodes seen
    changes: int          # surface changes detected in contact (S9)
    restarts: int         # times the surface became unknown (losses and changes)


class StiffnessLoop:
    """Estimator + k_s of the law, for one runtime."""

    def __init__(self, config: StiffnessConfig, n_W: np.ndarray, kernels: Any = None) -> None:
        """``kernels``: stiffness_kernels.py (tick_impl compiled; None: stiffness.py's Python)."""
        self.estimator = (StiffnessEstimator(config) if kernels is None
                          else CompiledStiffnessEstimator(config, kernels))
        self._n_W = np.array(n_W, dtype=float)
        self._n = tuple(self._n_W.tolist())  # n as floats: n^T p on floats
        self._known = False  # the estimate has been valid since the last reset
        self._touching = False
        self._paused = False  # the fit was paused in contact (update's learn)
        self.contacts = 0

    @property
    def k_hat(self) -> float:
        """
        Return the estimate, N/m; NaN while unknown.

        Unknown: never valid since the start or a new prior.
        """
        return self.estimator.k_hat if self._known else math.nan

    def configure(self, config: StiffnessConfig, n_W: np.ndarray,
                  ctrl: HybridForceController) -> None:
        """
        Install a parameter set, after ``ctrl.set_gains``.

        The estimate is kept unless the prior (``stiffness_k_hat0``: a restart from it),
        the bounds (``k_min``, ``k_max``: a restart from the clipped k_hat) or the normal
        ``n`` (x_n is another coordinate) change. Switching the estimate on starts the k_s
        command from the law's k_s; switching it off returns the law to the configured
        k_s at once (``lambda2 h`` continuous).
        """
        est = self.estimator
        was_enabled, old_prior = est.config.enabled, est.config.k_hat0
        est.reconfigure(config)
        if config.k_hat0 != old_prior:
            self._known = False
        if not np.array_equal(n_W, self._n_W):
            self._n_W[:] = n_W
            self._n = tuple(self._n_W.tolist())
            est.forget_data(restart_filter=True)
        if config.enabled and not was_enabled:
            est.set_k_s_command(ctrl.k_s)
        elif not config.enabled:
            ctrl.set_k_s(None)
        if config.enabled:
            ctrl.set_k_s(est.k_s)

    def update(self, ctrl: HybridForceController, f_n: float, p_W: np.ndarray,
               dt_state: float, dt_int: float, touching: bool,
               n: tuple[float, float, float] | None = None, learn: bool = True) -> None:
        """
        Process one new state: (S0)-(S6) on ``(f_n, n^T p_W)`` over ``dt_state`` (s, > 0).

        Then, when enabled, pass the k_s command (S7) over ``dt_int`` (s, > 0: the time the law
        integrates, bounded after a gap) into the law.

        ``f_n`` is the filtered normal force (N), ``p_W`` the tool position of the state
        (base frame, m), ``touching`` the runtime's contact state. ``n`` (a unit 3-tuple), when
        given, replaces the configured normal in ``x_n = n^T p_W``: a moving normal
        (runtime/surface.py). ``learn`` False pauses the fit in contact (the tool slides: x_n
        drifts with the normal's error); the first sample that learns again re-anchors it
        (stiffness.py ``re_anchor``: a new origin of x_n, k's information kept).
        """
        est = self.estimator
        restarts = est.restarts
        if touching and not self._touching:
            self.contacts += 1
        elif self._touching and not touching:
            est.restart()  # contact lost: the next surface is unknown
        self._touching = touching
        fit = touching and learn
        if touching and not learn:
            self._paused = True
        elif fit and self._paused:
            self._paused = False
            est.re_anchor()  # x_ref and b from the next sample on, k's information kept
        (n_x, n_y, n_z), (p_x, p_y, p_z) = self._n if n is None else n, p_W.tolist()
        est.update(f_n, n_x * p_x + n_y * p_y + n_z * p_z, dt_state, fit)  # x_n = n^T p_W
        self._known = est.valid or (self._known and est.restarts == restarts)
        if est.config.enabled:
            ctrl.set_k_s(est.k_s_command(dt_int), est.k_s_log_rate)

    def status(self, ctrl: HybridForceController) -> StiffnessStatus:
        """Snapshot for /diagnostics (the law's k_s and lambda2 in use)."""
        est = self.estimator
        near = est.near_k_max and (self._known or est.saturated)  # not the prior alone
        return StiffnessStatus(est.config.enabled, self.k_hat, est.k_hat_std, est.valid,
                               ctrl.k_s, ctrl.lambda2, near, est.saturated,
                               est.samples_used, est.samples_rejected, self.contacts,
                               est.changes, est.restarts)
