r"""
The runtime's steady tick in two compiled calls around pinocchio (``tick_impl: compiled``).

A steady tick (steady_tick.py says when a tick is one: running in the force loop, touching,
nothing under way but the run itself) is, in the Python reference
(controller_runtime.py ``tick``), some sixty calls: the latest inputs' filter, the run's clock,
the contact test, the reference, the law's step, the effort's limits. Here it is two kernels
around pinocchio's two regressor calls, each the arithmetic of its reference, formula for
formula:

- :func:`steady_front`: the task rows of the kinematics (robot_model.kinematics: ``x = p_W[ax]``,
  ``xdot = J qdot``), a new wrench into the base frame and through the low-pass filter
  (latest_inputs.filtered_force, filters.LowPassFilter), the normal force and the contact test
  (contact.in_contact), the time since the last state (run_clock.state_step), the tool's
  position along n (motion.note_contact), the reference's rows (step_kernels.reference_rows),
  the force loop's ``r_n``, ``rdot_n`` (control_law.force_loop_r_n) and step_kernels.law_front;
- :func:`steady_back`: step_kernels.law_back (eq. (5), eq. (26)), the force integral h (eq. (20),
  control_law._integrate_h), the effort's rate limit and clamp (effort.EffortLimiter),
  ``|e|`` for the recovery's statistics and, for a new state, the stiffness estimate's step
  and its k_s command (stiffness_loop.update: stiffness_kernels.update, k_s_command).

Neither changes the runtime's state until the tick is known to be steady: they write into the
workspace ``W`` (:func:`layout`) and the arrays they are given, and the caller commits
(steady_tick.py), so a tick that turns out not to be steady (contact lost, a singular pose, a
non-finite effort) runs the reference from the state it began with. Only the stiffness
estimate's state array is stepped in place, once the effort is finite. Numba's cache sees
only this file's stamp (step_kernels.py): it is dropped at import when a kernel file it calls
is newer.
"""
from __future__ import annotations

import math
from pathlib import Path

import numba as nb
from numba import boolean, float64, int64, types
import numpy as np

from .contact import CONTACT_FORCE_MIN_N
from ..law.kernels import _OPTS
from ..law.step_kernels import drop_stale_cache, law_back, law_front, reference_rows
from ..law.stiffness_kernels import ENABLED, k_s_command, LOG_RATE, RESTARTS, update, VALID

__all__ = ['layout', 'SC', 'steady_back', 'steady_front']

_HERE = Path(__file__)
for _dependency in ('law/kernels.py', 'law/step_kernels.py', 'law/stiffness_kernels.py',
                    'runtime/contact.py'):  # before they load (contact.py: its constant)
    drop_stale_cache(_HERE, _HERE.parents[1] / _dependency)

_A3, _A2, _A1, _I1 = float64[:, :, :], float64[:, :], float64[:], int64[:]
_W = float64[::1]  # the workspace: contiguous (its parts are reshaped)
#: the scalars steady_front and steady_back write at the head of W
SC = {name: i for i, name in enumerate((
    'dt_state', 'dt_int', 'why', 'f_n', 'x_seen', 'r_n', 'rdot_n', 'f_n_task', 'filter_dt',
    'filter_a', 'state', 'h', 'saturated', 'e_norm', 'known', 'k_s', 'log_rate'))}
N_SC = 20
WHY_STALE, WHY_LATE = 1.0, 2.0  # run_clock.state_step's 'stale' and 'late'


@nb.njit(types.UniTuple(int64, 16)(int64, int64), cache=True)
def layout(n, m):
    """
    Return where each part of the workspace W begins, for ``n`` joints and an ``m``-D task.

    In order: the scalars (SC), f_W, the reference's rows (3 x 3), x, xdot, J, Jdot, f,
    [r; rdot], e, J^#, N, qdot_r, qddot_r, V (the regressor's velocities, 2 x n) and the next
    theta_hat (to W's end).
    """
    y = N_SC
    rows = y + 3
    x = rows + 9
    xdot = x + m
    J = xdot + m
    Jdot = J + m * n
    f = Jdot + m * n
    rr = f + m
    e = rr + 2 * m
    J_inv = e + m
    N = J_inv + n * m
    qdot_r = N + n * n
    qddot_r = qdot_r + n
    V = qddot_r + n
    return 0, y, rows, x, xdot, J, Jdot, f, rr, e, J_inv, N, qdot_r, qddot_r, V, V + 2 * n


@nb.njit(nogil=True)
def _filter(W, y0, y, new_wrench, frame_ee, R, F_S, gap, cutoff, dt, a):
    """Write f_W (latest_inputs.filtered_force, LowPassFilter.update) at W[y0:]; its dt, a."""
    out = W[y0:y0 + 3]
    out[:] = y
    if not new_wrench:
        return dt, a
    u = np.empty(3)
    for i in range(3):
        if frame_ee:
            u[i] = -(R[i, 0] * F_S[0] + R[i, 1] * F_S[1] + R[i, 2] * F_S[2])
        else:
            u[i] = -F_S[i]
    if not math.isfinite(0.0 + u[0] + u[1] + u[2]):  # the sample is skipped, the state kept
        return dt, a
    if cutoff <= 0.0:
        out[:] = u
        return dt, a
    if gap != dt:
        dt = gap
        a = 1.0 - math.exp(-2.0 * math.pi * cutoff * max(gap, 0.0))
    for i in range(3):
        out[i] = y[i] + a * (u[i] - y[i])
    return dt, a


@nb.njit(int64(_W, int64, int64, _A2, _A2, _A1, _A2, _I1, _A1, boolean, boolean, _A1, float64,
               float64, float64, _A1, float64, float64, _A1, float64, float64, float64,
               float64, float64, _A1, _A1, float64, float64, float64, float64, float64,
               float64, _A3, float64, boolean, _A2, float64, float64, float64, _A2, float64,
               float64, _A2, _A2, _A2, float64), **_OPTS)
def steady_front(W, n, m, J6, Jdot6, p_W, R, ax, qdot, new_wrench, frame_ee, F_S, w_t, prev_t,
                 period, y, cutoff, filter_dt, n_W, f_d, t_state, t_used, limit, filter_a,
                 n_task, n_law, c, lambda1, lambda2, h, fdot_d, c_rate, K, omega, sine, base,
                 tau, tau_b, t_b, offsets, corr_tau, corr_tp, corr, G, M_inv, sigma0):
    """Fill W for the tick's first half; return 0 (steady), 1 (not touching), 2 (singular)."""
    o = layout(n, m)
    sc = W[:N_SC]
    x, xdot = W[o[3]:o[3] + m], W[o[4]:o[4] + m]
    J, Jdot = W[o[5]:o[6]].reshape((m, n)), W[o[6]:o[7]].reshape((m, n))
    for i in range(m):
        r = ax[i]
        x[i] = p_W[r]
        acc = 0.0
        for k in range(n):
            J[i, k], Jdot[i, k] = J6[r, k], Jdot6[r, k]
            acc += J6[r, k] * qdot[k]
        xdot[i] = acc
    gap = w_t - prev_t
    gap = gap if 0.0 < gap < 10.0 * period else period
    f_dt, f_a = _filter(W, o[1], y, new_wrench, frame_ee, R, F_S, gap, cutoff, filter_dt,
                        filter_a)
    f_W = W[o[1]:o[1] + 3]
    f_n = n_W[0] * f_W[0] + n_W[1] * f_W[1] + n_W[2] * f_W[2]
    if not f_n > max(CONTACT_FORCE_MIN_N, 0.1 * f_d):  # contact's hysteresis: the reference
        return 1
    if t_state <= t_used:  # run_clock.state_step without a gap
        dt, dt_int, why = 0.0, 0.0, WHY_STALE
    else:
        dt = period if t_used == -math.inf else t_state - t_used
        dt_int, why = min(dt, limit), (WHY_LATE if dt > limit else 0.0)
    x_seen = 0.0
    for i in range(m):
        x_seen += n_task[i] * x[i]
    rows = W[o[2]:o[3]].reshape((3, 3))
    reference_rows(K, omega, sine, base, tau, tau_b, t_b, offsets, corr_tau, corr_tp, corr,
                   rows)
    f = W[o[7]:o[7] + m]
    f_n_task = 0.0
    for i in range(m):
        f[i] = f_W[ax[i]]
        f_n_task += n_law[i] * f[i]
    df_n = f_n_task - f_d
    r_n = -(c * lambda1 * df_n + lambda2 * h)
    rdot_n = (c_rate * lambda1 - lambda2) * df_n
    if fdot_d:
        r_n += c * fdot_d
        rdot_n += lambda1 * c * fdot_d
    N = W[o[11]:o[12]].reshape((n, n)) if n > m else W[:0].reshape((0, 0))
    state = law_front(G, x, xdot, rows[0], rows[1], rows[2], r_n, rdot_n, J, Jdot, M_inv,
                      sigma0, qdot, W[o[8]:o[9]], W[o[9]:o[9] + m],
                      W[o[10]:o[11]].reshape((n, m)), N, W[o[12]:o[13]], W[o[13]:o[14]],
                      W[o[14]:o[15]].reshape((2, n)))
    if state < 0:
        return 2
    sc[0], sc[1], sc[2], sc[3], sc[4], sc[5], sc[6] = dt, dt_int, why, f_n, x_seen, r_n, rdot_n
    sc[7], sc[8], sc[9], sc[10] = f_n_task, f_dt, f_a, state
    return 0


@nb.njit(boolean(_W, int64, int64, _A2, _A2, _A2, boolean, _A1, float64, float64, _A2,
                 float64, float64, float64, float64, _A1, _A1, float64, float64, float64,
                 float64, _A1, float64, _A1, boolean, _A1, _A1, _A1, _A1, float64, float64,
                 float64, _A1, float64, boolean), **_OPTS)
def steady_back(W, n, m, R1, R2, P, known, theta_hat, k_d, k_null, Gamma_inv, k_a, error_limit,
                dead_zone, dt_adapt, lo, hi, h, h_limit, f_d, dt_int, qdot, max_rate, last,
                has_last, limits, tau, st, cf, n_x, n_y, n_z, p_W, dt_state, k_known):
    """
    Fill ``tau`` (limited), W's theta_hat and scalars, step ``st``; return tau's finiteness.

    ``theta_hat``'s next value (eq. (26), with ``dt_adapt`` > 0) goes to W's end. With
    ``dt_state`` > 0 the stiffness estimate (state ``st``, settings ``cf``: stiffness_kernels)
    takes the sample ``(f_n, n^T p_W)`` in contact, then, when enabled, gives its k_s command
    over ``dt_int``; ``k_known``: the loop's estimate known before (stiffness_loop.py).
    """
    o = layout(n, m)
    sc = W[:N_SC]
    p = theta_hat.shape[0]
    J = W[o[5]:o[6]].reshape((m, n))
    e = W[o[9]:o[9] + m]
    N = W[o[11]:o[12]].reshape((n, n)) if n > m else W[:0].reshape((0, 0))
    raw = np.empty(n)
    finite = law_back(R1, R2, P, known, theta_hat, J, W[o[7]:o[7] + m], k_d, e, N, qdot,
                      W[o[12]:o[13]], k_null, Gamma_inv, k_a, error_limit, dead_zone, dt_adapt,
                      lo, hi, raw, W[o[15]:o[15] + p])
    if not finite:
        return False
    if dt_int > 0.0:  # eq. (20), in contact: the steady tick touches
        h = min(max(h + (sc[7] - f_d) * dt_int, -h_limit), h_limit)
    saturated = False
    for i in range(n):
        v = raw[i]
        if max_rate > 0.0 and has_last:
            v = min(max(v, last[i] - max_rate), last[i] + max_rate)
        v = min(max(v, -limits[i]), limits[i])
        saturated = saturated or v != raw[i]
        tau[i] = v
    e2 = 0.0
    for i in range(m):
        e2 += e[i] * e[i]
    sc[11], sc[12], sc[13] = h, 1.0 if saturated else 0.0, math.sqrt(e2)
    if dt_state > 0.0:  # stiffness_loop.update, touching and learning
        restarts = st[RESTARTS]
        update(st, cf, sc[3], n_x * p_W[0] + n_y * p_W[1] + n_z * p_W[2], dt_state, True)
        k_known = st[VALID] != 0.0 or (k_known and st[RESTARTS] == restarts)
        sc[14] = 1.0 if k_known else 0.0
        if cf[ENABLED] != 0.0:
            sc[15] = k_s_command(st, cf, dt_int)
            sc[16] = st[LOG_RATE]
    return True
