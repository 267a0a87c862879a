r"""
The law's steady step in two compiled calls around pinocchio's regressor, and the reference.

The law's step in the force loop along the gains' n, the task translational (no approach, no
moving normal, no 6-D task: every tick of the paper's scenario, and the Panda's with n given),
is these two kernels and the two calls of pinocchio's regressor between them
(``RobotModel.regressor_pair``), where control_law.step runs about twenty numpy calls through
kernels.py's three. Each is the arithmetic its Python reference does, formula for formula:

- :func:`law_front`: eqs. (8) and (11), ``[r; rdot] = G z`` (control_law._linear_part), the error
  ``e = xdot - r``, then kernels.task_reference (eqs. (35)-(37)), and the two velocities of the
  regressor's polarisation (robot_model.regressor_affine, (R2)): ``v + w/8`` and
  ``sqrt2 (v - w/8)`` with ``v = qdot``, ``w = qdot_r``;
- :func:`law_back`: ``Y = (2 R1 - R2) P`` and ``tau_0`` ((R2)), eq. (5) in joint space
  (``tau = Y theta_hat + tau_0 + J^T (f - k_d e) - k_null N^T N s``, ``s = qdot - qdot_r``,
  kernels.effort) and, when asked, eq. (26)'s next theta_hat (kernels.adapt);
- :func:`reference_rows`: reference.BlendedReference.rows, the desired motion of every tick (the
  sine, or a held point's or a path's rows, with the blend from the arm and a correction).

The sums run in another order than numpy's, so the two agree to rounding (test_tick_impl
compares them on the paper's scenario, the Panda, a moving normal, a path and a fault episode).
Explicit signatures: compiled at import (``cache=True``), never in a tick; ``nogil``.

Numba's cache checks only the stamp of the file a kernel is defined in, not of the files whose
kernels it calls (numba's "Notes on Caching"). These call kernels.py's: the cache beside this
file is dropped here, at import, when kernels.py is newer than it (:func:`drop_stale_cache`), so
an edit of kernels.py is compiled in and never runs stale.
"""
from __future__ import annotations

import math
from pathlib import Path

import numba as nb
from numba import boolean, float64, int64, void
import numpy as np

from .kernels import _OPTS, adapt, effort, task_reference

__all__ = ['drop_stale_cache', 'law_back', 'law_front', 'reference_rows']


def drop_stale_cache(module: Path, dependency: Path) -> list[Path]:
    """
    Delete ``module``'s numba cache files that are older than ``dependency``; return them.

    The cache is ``__pycache__/<module stem>.*.nbi`` and ``.nbc`` beside ``module``.
    """
    cache = sorted((module.parent / '__pycache__').glob(f'{module.stem}.*.nb[ic]'))
    if not cache or min(p.stat().st_mtime for p in cache) >= dependency.stat().st_mtime:
        return []
    for path in cache:
        path.unlink(missing_ok=True)
    return cache


drop_stale_cache(Path(__file__), Path(__file__).with_name('kernels.py'))  # before they load

_A3, _A2, _A1 = float64[:, :, :], float64[:, :], float64[:]
_SQRT2 = math.sqrt(2.0)
CORRECT_VEL_S = 0.25  # reference.py's (test_tick_impl checks they are one value)


@nb.njit(int64(_A2, _A1, _A1, _A1, _A1, _A1, float64, float64, _A2, _A2, _A2, float64, _A1,
               _A1, _A1, _A2, _A2, _A1, _A1, _A2), **_OPTS)
def law_front(G, x, xdot, x_d, xdot_d, xddot_d, r_n, rdot_n, J, Jdot, M_inv, sigma0, qdot,
              rr, e, J_inv, N, qdot_r, qddot_r, V):
    """
    Fill ``[r; rdot]``, e, ``J^#``, N, ``qdot_r``, ``qddot_r`` and the regressor's velocities V.

    Returns task_reference's state (1 damped, 0 not, -1 singular). ``z = (x, xdot, x_d,
    xdot_d, xddot_d, r_n, rdot_n)`` as control_law._linear_part orders it.
    """
    m = x.shape[0]
    z = np.empty(2 * m + 11)
    z[:m], z[m:2 * m] = x, xdot
    z[2 * m:2 * m + 3], z[2 * m + 3:2 * m + 6], z[2 * m + 6:2 * m + 9] = x_d, xdot_d, xddot_d
    z[2 * m + 9], z[2 * m + 10] = r_n, rdot_n
    for i in range(2 * m):
        acc = 0.0
        for k in range(2 * m + 11):
            acc += G[i, k] * z[k]
        rr[i] = acc
    for i in range(m):
        e[i] = xdot[i] - rr[i]
    state = task_reference(M_inv, J, Jdot, rr[:m], rr[m:], sigma0, J_inv, N, qdot_r, qddot_r)
    for i in range(qdot.shape[0]):
        V[0, i] = qdot[i] + 0.125 * qdot_r[i]
        V[1, i] = _SQRT2 * qdot[i] + (-_SQRT2 / 8.0) * qdot_r[i]
    return state


@nb.njit(boolean(_A2, _A2, _A2, boolean, _A1, _A2, _A1, float64, _A1, _A2, _A1, _A1, float64,
                 _A2, float64, float64, float64, float64, _A1, _A1, _A1, _A1), **_OPTS)
def law_back(R1, R2, P, known, theta_hat, J_ee, f, k_d, e, N, qdot, qdot_r, k_null, Gamma_inv,
             k_a, error_limit, dead_zone, dt, lo, hi, tau, theta_out):
    """
    Fill ``tau`` (eq. 5) and, with ``dt`` > 0, ``theta_out`` (eq. 26); return tau's finiteness.

    ``P`` maps the regressor's columns to theta (``known``: its last column is the known part
    pi_0, giving tau_0). ``dt`` 0 leaves ``theta_out`` as it is.
    """
    n, p = R1.shape[0], theta_hat.shape[0]
    Y = np.zeros((n, P.shape[1]))
    for i in range(n):
        for k in range(R1.shape[1]):
            r = 2.0 * R1[i, k] - R2[i, k]
            if r != 0.0:
                for c in range(P.shape[1]):
                    Y[i, c] += r * P[k, c]
    Y_q = Y[:, :p]
    tau_0 = Y[:, p] if known else Y[:0, 0]
    m = f.shape[0]
    f_kde = np.empty(m)
    for k in range(m):
        f_kde[k] = f[k] - k_d * e[k]
    s = qdot - qdot_r
    finite = effort(Y_q, theta_hat, tau_0, J_ee, f_kde, Y[:0, :], Y[0, :0], N, s, k_null, tau)
    if finite and dt > 0.0:
        adapt(theta_hat, Gamma_inv, Y_q, s, e, k_a, error_limit, dead_zone, dt, lo, hi,
              theta_out)
    return finite


@nb.njit(nogil=True)
def _hermite(t, T, out):
    """reference._hermite: fill ``out`` (3, 2) with the blend weights at ``t`` of ``T``."""
    s = t / T
    out[0, 0] = 1.0 - 10 * s**3 + 15 * s**4 - 6 * s**5
    out[0, 1] = T * (s - 6 * s**3 + 8 * s**4 - 3 * s**5)
    out[1, 0] = (-30 * s**2 + 60 * s**3 - 30 * s**4) / T
    out[1, 1] = 1.0 - 18 * s**2 + 32 * s**3 - 15 * s**4
    out[2, 0] = (-60 * s + 180 * s**2 - 120 * s**3) / T**2
    out[2, 1] = (-36 * s + 96 * s**2 - 60 * s**3) / T


@nb.njit(void(_A3, float64, boolean, _A2, float64, float64, float64, _A2, float64, float64,
              _A2, _A2), **_OPTS)
def reference_rows(K, omega, sine, base, tau, tau_b, t_b, offsets, corr_tau, corr_tp, corr,
                   out):
    """
    Fill ``out`` with reference.BlendedReference.rows at ``tau``: x_d, xdot_d, xddot_d.

    The base is the sine ``K (1, sin wt, cos wt)`` (``sine``) or ``base``'s rows (a held point,
    a path); then the blend of ``offsets`` (dp, dv) over ``t_b`` from ``tau_b``, and a
    correction ``corr`` (dp, dv) from ``corr_tau``: its velocity over CORRECT_VEL_S, its
    position over ``corr_tp``.
    """
    if sine:
        wt = omega * tau
        sn, cs = math.sin(wt), math.cos(wt)
        for i in range(3):
            for j in range(3):
                out[i, j] = K[i, j, 0] + K[i, j, 1] * sn + K[i, j, 2] * cs
    else:
        out[:, :] = base
    H = np.empty((3, 2))
    t = tau - tau_b
    if not (t_b <= 0.0 or t >= t_b):
        _hermite(t, t_b, H)
        for i in range(3):
            for j in range(3):
                out[i, j] += H[i, 0] * offsets[0, j] + H[i, 1] * offsets[1, j]
    t = tau - corr_tau
    if 0.0 <= t < CORRECT_VEL_S:
        _hermite(t, CORRECT_VEL_S, H)
        for i in range(3):
            for j in range(3):
                out[i, j] += H[i, 1] * corr[1, j]
    if 0.0 <= t < corr_tp:
        _hermite(t, corr_tp, H)
        for i in range(3):
            for j in range(3):
                out[i, j] += H[i, 0] * corr[0, j]
