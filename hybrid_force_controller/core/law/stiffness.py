"""
Online estimate of the surface stiffness k along n, from the contact model (12)-(13) of [1].

[1] Jafari et al., "An Adaptive Hybrid Force/Motion Control Design for Robot Manipulators
Interacting in Constrained Motion with Unknown Non-Rigid Environments". Pure Python: the
2 x 2 closed forms on floats need no numpy. Time is an argument, nothing reads a clock, nothing
is allocated per call beyond Python floats. Equations (S0)-(S8) are this module's;
docs/design.md, "Online stiffness estimate", gives the reasons and figures.

Model: (12)-(13) along n, ``f_n = n^T f``, ``x_n = n^T x`` (base frame), in contact::

    f_n = k (x_n - x0_n)                                                                (S1)

``x_n`` passes through the caller's first-order force filter (cut-off ``f_c``) so that
the filtered pair obeys (S1) exactly (unit DC gain; a lag on one side only biases k)::

    x_n <- x_n,f + a (x_n - x_n,f),   a = 1 - exp(-2 pi f_c dt)                         (S0)

With a local origin ``x_ref`` (x_n at the first contact sample) and the scale ``k_max``::

    f_n = phi^T theta,  phi = (u, 1),  u = k_max (x_n - x_ref) [N],
                        theta = (kappa, b),  kappa = k / k_max,  b = k (x_ref - x0_n)    (S2)

Recursive least squares with forgetting, regularised towards ``theta0 = (k_prior / k_max,
f_n(x_ref))``, information form (``R = P^-1``), over *exciting* in-contact samples j::

    R_j     = lam R_{j-1} + (1 - lam) rho D + phi phi^T,   lam = exp(-dt / T_f)          (S3)
    theta_j = theta_{j-1} + R_j^-1 [(1 - lam) rho D (theta0 - theta_{j-1})
                                    + phi (f_n - phi^T theta_{j-1})]                    (S4)

``D = diag(1 N^2, 1)``; then ``kappa`` is projected onto ``[k_min, k_max] / k_max`` in the
metric R. Excitation (a dead zone on the regressor, never on the force: no bias), with
``x_bar`` an exponential mean of x_n over ``T_e``::

    k_e |x_n - x_bar| >= delta_f,   k_e = k_hat if valid (S6) else k_max                (S5)

A sample that is not exciting changes nothing (no forgetting, no drift). Validity, with
``s2`` the forgetting-weighted mean squared residual (floored) and ``w`` the effective
number of samples::

    sigma_k = k_max sqrt(s2 (R^-1)_uu),
    valid  <=>  w >= 20  and  sigma_k <= tol k_hat  and  the bounds were not active      (S6)

k_s command: a first-order lag in log space, rate-limited, down only to a valid estimate::

    d ln k_s / dt = clip((ln k_target - ln k_s) / T_s, -rate_down, rate_up),             (S7)
    k_target = k_hat if valid or k_hat > k_s, else k_s (held);

and the warning ``near_k_max <=> k_hat >= (1 - margin) k_max``.                          (S8)

Change test on every in-contact sample of a valid estimate (a CUSUM of the a-priori
residual ``eps = f_n - phi^T theta``: the surface's k or x0 changed under the tool)::

    S_j = max(0, S_{j-1} + (|eps_j| - delta_c) dt),   change  <=>  S_j > delta_c T_c     (S9)

A change, and a contact loss (the caller's :meth:`StiffnessEstimator.restart`), make the
surface unknown again: the fit restarts from the prior and the k_s command jumps to
``max(k_s, k_s0)``, never a higher loop gain than the configured k_s gives.

Once the estimate is valid, an in-contact sample whose raw ``x_n`` is further from the last
learnt one than a settled contact moves along n in that time, ``v_max dt``
(:data:`MAX_NORMAL_SPEED`), waits for the next sample, which says what it was::

    |x_n,j - x_n,j-1| > v_max dt_j  and  |x_n,j+1 - x_n,j-1| <= v_max (dt_j + dt_j+1)
        =>  sample j is a spike: refused, never learnt, not even by the filter (S0)      (S10)

otherwise it was motion (or a new coordinate) and is learnt, one sample late, exactly as
without (S10). So real motion of any speed is learnt in full, and nothing is locked out.

A joint state within the input checks (``max_joint_jump``, 0.01 rad by default) may still
place the tool a centimetre off for one sample: a corrupted or stray message. Through (S0)
such a spike is a leverage point of the fit; a fuzz of corrupted messages taught a valid
k_hat of 50-300 N/m on a 1700 N/m surface, and k_s followed it down to a fifth of k, where
the force loop breaks (a 504 N impact; docs/results.md, section 25). Before the estimate is
valid (a first contact's loading) nothing waits.
"""
from __future__ import annotations

import math

from ..config.groups import StiffnessConfig, StiffnessConfigError, StiffnessError

__all__ = ['MAX_NORMAL_SPEED', 'MIN_SAMPLES', 'StiffnessConfig',
           'StiffnessConfigError', 'StiffnessError', 'StiffnessEstimator']

MIN_SAMPLES = 20.0  # effective exciting samples before the estimate may be valid (S6)
MAX_NORMAL_SPEED = 0.1  # v_max of (S10), m/s: 0.1 mm per 1 ms sample (a contact: mm/s)
CHANGE_TIME = 0.02  # T_c of (S9), s: |eps| must exceed delta_c by this much force x time


class StiffnessEstimator:
    """
    Recursive estimate of the surface stiffness, eqs. (S0)-(S8) of the module docstring.

    Call :meth:`update` once per new state with the filtered normal force and the tool
    position along ``n``, then :meth:`k_s_command` for the value to use as k_s.
    """

    def __init__(self, config: StiffnessConfig) -> None:
        if not isinstance(config, StiffnessConfig):
            raise StiffnessConfigError(f'expected a StiffnessConfig, got {type(config).__name__}')
        self.config = config
        self._dt_cache = (-1.0,) * 5  # dt, lam (S3), alpha of x_bar (S5), a (S0), lag of (S7)
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self, k_hat0: float | None = None) -> None:
        """Forget all data; restart k_hat and k_s from ``k_hat0`` (default: the config's prior)."""
        k0 = self.config.prior if k_hat0 is None else float(k_hat0)
        self._x_f: float | None = None  # x_n through the force filter (S0)
        self._x_last: float | None = None  # the last learnt in-contact raw x_n (S10)
        self.forget_data(k0)
        self._k_s = k0
        self.k_s_log_rate = 0.0  # d ln k_s / dt of the last k_s_command (for rdot)
        self.excited = False
        self.excitation_n = 0.0  # k_e |x_n - x_bar| of the last in-contact sample (S5), N
        self.samples_used = self.samples_rejected = self.restarts = self.changes = 0

    def forget_data(self, k_prior: float | None = None, *, restart_filter: bool = False) -> None:
        """
        Restart the regression (S2)-(S6) from the prior ``k_prior`` (default: the current k_hat).

        The k_s command, the counters and (unless ``restart_filter``, for a new normal) the filter
        (S0) are kept. For a new contact, when the surface may have changed: the information of
        a long loading otherwise outweighs a new surface for several ``T_f``.
        """
        c = self.config
        k0 = self.k_hat if k_prior is None else float(k_prior)
        if not (math.isfinite(k0) and c.k_min <= k0 <= c.k_max):
            raise StiffnessError(f'prior k_hat0 = {k0} is outside [{c.k_min:g}, {c.k_max:g}]')
        self._kappa0 = self._kappa = k0 / c.k_max
        self._b = self._b0 = 0.0
        rho = c.regularisation
        self._r_uu, self._r_ub, self._r_bb = rho, 0.0, rho  # R of (S3), symmetric
        self._x_ref: float | None = None
        self._x_bar = 0.0
        if restart_filter:
            self._x_f = self._x_last = None
        self._cusum = 0.0  # S of (S9), N s
        self.saturated = False  # the projection onto [k_min, k_max] was active (S6)
        self._w = self._s2_sum = 0.0  # effective sample count and weighted residual^2 (S6)
        self._valid = False  # (S6), evaluated once per change of the fit
        # (S10): a far sample (f_n, x_n, dt) held for the old fit is not the new fit's first
        self._held: tuple[float, float, float] | None = None

    def re_anchor(self) -> None:
        """
        Forget where x_n's origin is, keep what the data said of k: a new local origin (S2).

        For an x_n that jumped or drifted while the fit was paused (a moving normal,
        runtime/surface.py): the next in-contact sample sets ``x_ref`` and b as a first contact
        does, and the filter (S0) starts again from it; the information of kappa is kept as its
        marginal over b (the Schur complement ``r_uu - r_ub^2 / r_bb`` of R), b's is the
        prior's. k_hat, its validity and the k_s command are kept.
        """
        rho = self.config.regularisation
        self._r_uu = max(self._r_uu - self._r_ub * self._r_ub / self._r_bb, rho)
        self._r_ub, self._r_bb = 0.0, rho
        self._x_ref, self._x_f, self._cusum = None, None, 0.0  # (S0) restarts at the new x_n
        self._x_last = self._held = None  # (S10): the new x_n is no jump

    def restart(self) -> None:
        """
        Treat the surface as unknown again (contact lost, or a change (S9)).

        The fit restarts from the prior, the k_s command jumps to ``max(k_s, k_s0)``.
        """
        self.forget_data(self.config.prior)
        self._k_s, self.k_s_log_rate = max(self._k_s, self.config.k_s0), 0.0
        self.restarts += 1

    def reconfigure(self, config: StiffnessConfig) -> None:
        """
        Install new settings, keeping the estimate where they allow it.

        A new prior (``k_hat0``), new bounds or a new ``k_max`` restart the regression
        from the current k_hat (clipped; the prior if ``k_hat0`` changed); every other
        setting applies from the next sample on. The k_s command is kept.
        """
        if not isinstance(config, StiffnessConfig):
            raise StiffnessConfigError(f'expected a StiffnessConfig, got {type(config).__name__}')
        old, k_hat = self.config, self.k_hat
        self.config, self._dt_cache = config, (-1.0,) * 5
        if config.k_hat0 != old.k_hat0:
            self.forget_data(config.prior)
        elif (config.k_min, config.k_max) != (old.k_min, old.k_max):
            self.forget_data(min(max(k_hat, config.k_min), config.k_max))
        self._refresh_validity()  # valid_tol and force_floor enter (S6)

    def set_k_s_command(self, k_s: float) -> None:
        """
        Restart the k_s command (S7) from ``k_s``, N/m.

        For example from the k_s in use when the estimate is switched on.
        """
        if not (isinstance(k_s, (int, float)) and math.isfinite(k_s) and k_s > 0.0):
            raise StiffnessError(f'k_s must be finite and > 0, got {k_s!r}')
        self._k_s, self.k_s_log_rate = float(k_s), 0.0

    @property
    def k_hat(self) -> float:
        """Return the current estimate, N/m, always in ``[k_min, k_max]``."""
        return self._kappa * self.config.k_max

    @property
    def k_hat_std(self) -> float:
        """Return the standard deviation of k_hat from (S6), N/m (large before excitation)."""
        det = self._r_uu * self._r_bb - self._r_ub * self._r_ub
        s2 = max(self._s2_sum / self._w if self._w > 0.0 else 0.0, self.config.force_floor ** 2)
        return self.config.k_max * math.sqrt(s2 * self._r_bb / det)

    @property
    def valid(self) -> bool:
        """(S6): enough exciting samples, a small relative standard deviation, not at a bound."""
        return self._valid

    def _refresh_validity(self) -> None:
        """Evaluate (S6) after the fit changed (``valid`` is read several times per sample)."""
        self._valid = (self._w >= MIN_SAMPLES and not self.saturated
                       and self.k_hat_std <= self.config.valid_tol * self.k_hat)

    @property
    def near_k_max(self) -> bool:
        """(S8): k_hat is within the margin of k_max, where eq. (29) loses its margin."""
        return self.k_hat >= (1.0 - self.config.k_max_margin) * self.config.k_max

    @property
    def k_s(self) -> float:
        """Return the last k_s command, N/m."""
        return self._k_s

    # ------------------------------------------------------------------ update
    def _factors(self, dt: float) -> tuple[float, float, float, float, float]:
        """``(dt, lam, alpha, a, lag)``: (S3), the x_bar gain of (S5), (S0), (S7) (cached)."""
        if dt != self._dt_cache[0]:  # (the cached dt was checked)
            if not (isinstance(dt, (int, float)) and dt > 0.0 and math.isfinite(dt)):
                raise StiffnessError(f'dt must be finite and > 0, got {dt!r}')
            c = self.config
            w_c, T_s = 2.0 * math.pi * c.force_filter_hz, c.k_s_time_constant
            self._dt_cache = (dt, math.exp(-dt / c.time_constant),
                              -math.expm1(-dt / c.excitation_window),
                              1.0 if w_c == 0.0 else -math.expm1(-w_c * dt),
                              1.0 if T_s == 0.0 else -math.expm1(-dt / T_s))
        return self._dt_cache

    def update(self, f_n: float, x_n: float, dt: float, in_contact: bool) -> float:
        """
        Feed one sample; return k_hat (N/m).

        Non-finite ``f_n`` / ``x_n``, and a spike of ``x_n`` (S10), are ignored and counted
        (``samples_rejected``); a sample far from the last waits for the next one (S10).
        Raises :class:`StiffnessError` on a bad ``dt`` or a non-numeric sample.

        Parameters
        ----------
        f_n : float
            Normal force the tool exerts on the surface, ``n^T f``, N, filtered by the
            controller's first-order filter (``config.force_filter_hz``).
        x_n : float
            Tool position along the normal, ``n^T x``, base frame, m, unfiltered (it passes
            through the same filter here, (S0)).
        dt : float
            Time since the previous sample, s (finite, > 0).
        in_contact : bool
            The caller's contact test; samples out of contact are ignored.

        """
        self._factors(dt)  # checks dt
        self.excited, self.excitation_n = False, 0.0
        try:
            f_n, x_n = float(f_n), float(x_n)
        except (TypeError, ValueError):
            raise StiffnessError(f'f_n and x_n must be numbers, got {f_n!r}, {x_n!r}') from None
        if not (math.isfinite(f_n) and math.isfinite(x_n)):
            self.samples_rejected += 1
            return self.k_hat
        held, self._held = self._held, None
        if held is not None:  # (S10): the sample after a far one says what the far one was
            if in_contact and abs(x_n - self._x_last) <= MAX_NORMAL_SPEED * (held[2] + dt):
                self.samples_rejected += 1  # back where it was: a spike, never learnt
                dt += held[2]
            else:
                self._step(*held, True)  # motion: learnt one sample late
        elif (in_contact and self._valid and self._x_last is not None
              and abs(x_n - self._x_last) > MAX_NORMAL_SPEED * dt):
            self._held = (f_n, x_n, dt)
            return self.k_hat
        return self._step(f_n, x_n, dt, in_contact)

    def _step(self, f_n: float, x_n: float, dt: float, in_contact: bool) -> float:
        """(S0)-(S9) on one finite sample that (S10) let through."""
        _, lam, alpha, a, _ = self._factors(dt)
        self._x_last = x_n if in_contact else None
        self._x_f = x_n if self._x_f is None else self._x_f + a * (x_n - self._x_f)  # (S0)
        x_n = self._x_f
        if not in_contact:
            return self.k_hat
        if self._x_ref is not None and self._changed(f_n, x_n, dt):
            self.changes += 1
            self.restart()
        if self._x_ref is None:  # first contact: local origin and prior of b (S2)
            self._x_ref = self._x_bar = x_n
            self._b = self._b0 = f_n
            return self.k_hat
        deviation = abs(x_n - self._x_bar)
        self._x_bar += alpha * (x_n - self._x_bar)
        self.excitation_n = (self.k_hat if self._valid else self.config.k_max) * deviation
        if self.excitation_n < self.config.excitation or deviation == 0.0:  # (S5)
            return self.k_hat
        self.excited = True
        self.samples_used += 1
        self._rls_step(self.config.k_max * (x_n - self._x_ref), f_n, lam)
        return self.k_hat

    def _changed(self, f_n: float, x_n: float, dt: float) -> bool:
        """(S9) on one in-contact sample; only a valid estimate is tested."""
        c = self.config
        if c.change_force == 0.0 or not self._valid:
            self._cusum = 0.0
            return False
        eps = f_n - (c.k_max * (x_n - self._x_ref) * self._kappa + self._b)
        self._cusum = max(0.0, self._cusum + (abs(eps) - c.change_force) * dt)
        return self._cusum > c.change_force * CHANGE_TIME

    def _rls_step(self, u: float, f_n: float, lam: float) -> None:
        """(S3), (S4), the projection onto the bounds and the residual statistics (S6)."""
        c = self.config
        reg = (1.0 - lam) * c.regularisation
        r_uu = lam * self._r_uu + reg + u * u
        r_ub = lam * self._r_ub + u
        r_bb = lam * self._r_bb + reg + 1.0
        kappa, b = self._kappa, self._b
        err = f_n - (u * kappa + b)
        g_u = reg * (self._kappa0 - kappa) + u * err  # bracket of (S4)
        g_b = reg * (self._b0 - b) + err
        det = r_uu * r_bb - r_ub * r_ub
        d_kappa = (r_bb * g_u - r_ub * g_b) / det
        d_b = (r_uu * g_b - r_ub * g_u) / det
        kappa, b = kappa + d_kappa, b + d_b
        clipped = min(max(kappa, c.k_min / c.k_max), 1.0)
        b -= r_ub / r_bb * (clipped - kappa)  # projection in the metric R
        self._kappa, self._b = clipped, b
        self.saturated = bool(clipped != kappa)
        self._r_uu, self._r_ub, self._r_bb = r_uu, r_ub, r_bb
        post = f_n - (u * clipped + b)
        self._w, self._s2_sum = lam * self._w + 1.0, lam * self._s2_sum + post * post
        self._refresh_validity()

    # ------------------------------------------------------------------ k_s
    def k_s_command(self, dt: float) -> float:
        """
        Advance and return the k_s command (S7), N/m.

        Down to a valid k_hat, up to any (a command outside ``[k_min, k_max]``, e.g. after new
        bounds, moves into them). Disabled: held.
        """
        lag = self._factors(dt)[4]
        c = self.config
        k_hat, k_s = self.k_hat, self._k_s
        target = (k_s if not c.enabled else k_hat if k_hat > k_s or self._valid
                  else min(max(k_s, c.k_min), c.k_max))
        step = math.log(target / k_s) * lag
        step = min(max(step, -c.k_s_rate_down * dt), c.k_s_rate_up * dt)
        self._k_s = k_s * math.exp(step)
        self.k_s_log_rate = step / dt
        return self._k_s
