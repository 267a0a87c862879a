r"""
The stiffness estimate's per-sample step, compiled (``tick_impl: compiled``; stiffness.py).

:func:`update` is ``StiffnessEstimator.update`` ((S0)-(S6), (S9), (S10), with the restart a change
makes) and :func:`k_s_command` its (S7), on the estimator's state held in one float64 array
(:data:`STATE`: a name of stiffness.py's attributes to its slot; None is NaN, a flag 0 or 1)
and its settings in another (:data:`CONFIG`). stiffness_compiled.py keeps the estimator's
Python interface on those arrays; every rare step (a reset, a new prior, re-anchoring, new
settings) stays stiffness.py's Python. Same formulas, same order: test_tick_impl compares the
two estimators sample by sample. Explicit signatures: compiled at import (``cache=True``).
"""
from __future__ import annotations

import math

import numba as nb
from numba import boolean, float64

from .kernels import _OPTS

__all__ = ['CHANGE_TIME', 'CONFIG', 'MAX_NORMAL_SPEED', 'MIN_SAMPLES', 'STATE', 'k_s_command',
           'update']

MIN_SAMPLES = 20.0  # stiffness.py's (test_tick_impl checks that they are one value)
MAX_NORMAL_SPEED = 0.1
CHANGE_TIME = 0.02

STATE = {name: i for i, name in enumerate((
    '_x_f', '_x_last', '_x_ref', '_x_bar', '_b', '_b0', '_kappa', '_kappa0', '_r_uu', '_r_ub',
    '_r_bb', '_cusum', 'saturated', '_w', '_s2_sum', '_valid', '_held', '_held_f', '_held_x',
    '_held_dt', '_k_s', 'k_s_log_rate', 'excited', 'excitation_n', 'samples_used',
    'samples_rejected', 'restarts', 'changes'))}
CONFIG = ('enabled', 'k_min', 'k_max', 'k_s0', 'prior', 'time_constant', 'excitation',
          'excitation_window', 'valid_tol', 'k_s_time_constant', 'k_s_rate_down', 'k_s_rate_up',
          'change_force', 'regularisation', 'force_floor', 'force_filter_hz')
(X_F, X_LAST, X_REF, X_BAR, B, B0, KAPPA, KAPPA0, R_UU, R_UB, R_BB, CUSUM, SATURATED, W, S2_SUM,
 VALID, HELD, HELD_F, HELD_X, HELD_DT, K_S, LOG_RATE, EXCITED, EXCITATION_N, SAMPLES_USED,
 SAMPLES_REJECTED, RESTARTS, CHANGES) = range(len(STATE))
(ENABLED, K_MIN, K_MAX, K_S0, PRIOR, T_F, EXCITATION, T_E, VALID_TOL, T_S, RATE_DOWN, RATE_UP,
 CHANGE_FORCE, RHO, FORCE_FLOOR, F_C) = range(len(CONFIG))
_A1 = float64[:]


@nb.njit(nogil=True)
def _forget(st, cf, k0):
    """forget_data(k0) without restarting the filter (the prior is valid: the settings')."""
    st[KAPPA0] = st[KAPPA] = k0 / cf[K_MAX]
    st[B] = st[B0] = 0.0
    st[R_UU], st[R_UB], st[R_BB] = cf[RHO], 0.0, cf[RHO]
    st[X_REF], st[X_BAR], st[CUSUM], st[SATURATED] = math.nan, 0.0, 0.0, 0.0
    st[W] = st[S2_SUM] = 0.0
    st[VALID], st[HELD] = 0.0, 0.0


@nb.njit(nogil=True)
def _refresh_validity(st, cf):
    """(S6), as stiffness.py's _refresh_validity and k_hat_std."""
    st[VALID] = 0.0
    if st[W] >= MIN_SAMPLES and st[SATURATED] == 0.0:
        det = st[R_UU] * st[R_BB] - st[R_UB] * st[R_UB]
        s2 = max(st[S2_SUM] / st[W] if st[W] > 0.0 else 0.0, cf[FORCE_FLOOR] ** 2)
        if cf[K_MAX] * math.sqrt(s2 * st[R_BB] / det) <= cf[VALID_TOL] * (st[KAPPA] * cf[K_MAX]):
            st[VALID] = 1.0


@nb.njit(nogil=True)
def _rls_step(st, cf, u, f_n, lam):
    """(S3), (S4), the projection onto the bounds and (S6), as stiffness.py's _rls_step."""
    reg = (1.0 - lam) * cf[RHO]
    r_uu = lam * st[R_UU] + reg + u * u
    r_ub = lam * st[R_UB] + u
    r_bb = lam * st[R_BB] + reg + 1.0
    kappa, b = st[KAPPA], st[B]
    err = f_n - (u * kappa + b)
    g_u = reg * (st[KAPPA0] - kappa) + u * err
    g_b = reg * (st[B0] - b) + err
    det = r_uu * r_bb - r_ub * r_ub
    d_kappa = (r_bb * g_u - r_ub * g_b) / det
    d_b = (r_uu * g_b - r_ub * g_u) / det
    kappa, b = kappa + d_kappa, b + d_b
    clipped = min(max(kappa, cf[K_MIN] / cf[K_MAX]), 1.0)
    b -= r_ub / r_bb * (clipped - kappa)
    st[KAPPA], st[B] = clipped, b
    st[SATURATED] = 1.0 if clipped != kappa else 0.0
    st[R_UU], st[R_UB], st[R_BB] = r_uu, r_ub, r_bb
    post = f_n - (u * clipped + b)
    st[W], st[S2_SUM] = lam * st[W] + 1.0, lam * st[S2_SUM] + post * post
    _refresh_validity(st, cf)


@nb.njit(nogil=True)
def _changed(st, cf, f_n, x_n, dt):
    """(S9), as stiffness.py's _changed."""
    if cf[CHANGE_FORCE] == 0.0 or st[VALID] == 0.0:
        st[CUSUM] = 0.0
        return False
    eps = f_n - (cf[K_MAX] * (x_n - st[X_REF]) * st[KAPPA] + st[B])
    st[CUSUM] = max(0.0, st[CUSUM] + (abs(eps) - cf[CHANGE_FORCE]) * dt)
    return st[CUSUM] > cf[CHANGE_FORCE] * CHANGE_TIME


@nb.njit(nogil=True)
def _step(st, cf, f_n, x_n, dt, in_contact):
    """(S0)-(S9) on one finite sample, as stiffness.py's _step."""
    lam = math.exp(-dt / cf[T_F])
    alpha = -math.expm1(-dt / cf[T_E])
    w_c = 2.0 * math.pi * cf[F_C]
    a = 1.0 if w_c == 0.0 else -math.expm1(-w_c * dt)
    st[X_LAST] = x_n if in_contact else math.nan
    st[X_F] = x_n if math.isnan(st[X_F]) else st[X_F] + a * (x_n - st[X_F])
    x_n = st[X_F]
    if not in_contact:
        return
    if not math.isnan(st[X_REF]) and _changed(st, cf, f_n, x_n, dt):
        st[CHANGES] += 1.0
        _forget(st, cf, cf[PRIOR])  # restart()
        st[K_S], st[LOG_RATE] = max(st[K_S], cf[K_S0]), 0.0
        st[RESTARTS] += 1.0
    if math.isnan(st[X_REF]):
        st[X_REF] = st[X_BAR] = x_n
        st[B] = st[B0] = f_n
        return
    deviation = abs(x_n - st[X_BAR])
    st[X_BAR] += alpha * (x_n - st[X_BAR])
    st[EXCITATION_N] = (st[KAPPA] * cf[K_MAX] if st[VALID] != 0.0 else cf[K_MAX]) * deviation
    if st[EXCITATION_N] < cf[EXCITATION] or deviation == 0.0:
        return
    st[EXCITED] = 1.0
    st[SAMPLES_USED] += 1.0
    _rls_step(st, cf, cf[K_MAX] * (x_n - st[X_REF]), f_n, lam)


@nb.njit(nogil=True)
def _update(st, cf, f_n, x_n, dt, in_contact):
    """StiffnessEstimator.update's body: (S10), then (S0)-(S9) on the sample it lets through."""
    st[EXCITED], st[EXCITATION_N] = 0.0, 0.0
    if not (math.isfinite(f_n) and math.isfinite(x_n)):
        st[SAMPLES_REJECTED] += 1.0
        return
    held = st[HELD] != 0.0
    st[HELD] = 0.0
    if held:  # (S10): the sample after a far one says what the far one was
        if in_contact and abs(x_n - st[X_LAST]) <= MAX_NORMAL_SPEED * (st[HELD_DT] + dt):
            st[SAMPLES_REJECTED] += 1.0
            dt += st[HELD_DT]
        else:
            _step(st, cf, st[HELD_F], st[HELD_X], st[HELD_DT], True)
    elif (in_contact and st[VALID] != 0.0 and not math.isnan(st[X_LAST])
          and abs(x_n - st[X_LAST]) > MAX_NORMAL_SPEED * dt):
        st[HELD], st[HELD_F], st[HELD_X], st[HELD_DT] = 1.0, f_n, x_n, dt
        return
    _step(st, cf, f_n, x_n, dt, in_contact)


@nb.njit(float64(_A1, _A1, float64, float64, float64, boolean), **_OPTS)
def update(st, cf, f_n, x_n, dt, in_contact):
    """StiffnessEstimator.update on ``st``; return k_hat (N/m), as it does."""
    _update(st, cf, f_n, x_n, dt, in_contact)
    return st[KAPPA] * cf[K_MAX]


@nb.njit(float64(_A1, _A1, float64), **_OPTS)
def k_s_command(st, cf, dt):
    """StiffnessEstimator.k_s_command on ``st``: advance and return the k_s command (S7)."""
    T_s = cf[T_S]
    lag = 1.0 if T_s == 0.0 else -math.expm1(-dt / T_s)
    k_hat, k_s = st[KAPPA] * cf[K_MAX], st[K_S]
    target = (k_s if cf[ENABLED] == 0.0 else k_hat if k_hat > k_s or st[VALID] != 0.0
              else min(max(k_s, cf[K_MIN]), cf[K_MAX]))
    step = math.log(target / k_s) * lag
    step = min(max(step, -cf[RATE_DOWN] * dt), cf[RATE_UP] * dt)
    st[K_S] = k_s * math.exp(step)
    st[LOG_RATE] = step / dt
    return st[K_S]
