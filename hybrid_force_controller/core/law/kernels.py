r"""
Compiled kernels of the law's tick (``tick_impl: compiled``, numba): three calls per step.

Each writes into arrays its caller allocated and returns a number: no array is boxed on the way
out, so no Python runs inside a call (boxing an array unpickles its dtype: a Python frame in
which a Ctrl-C became a SystemError).

Each kernel computes what its Python reference (tick_impl.py, ``PythonTick``) computes, with
the same formulas; only the order of the sums differs (numpy's BLAS against plain loops), so
the two agree to rounding (test_tick_impl):

- :func:`task_reference`: the task inverse, damped near a singularity (task_inverse.py for a
  redundant arm, linalg.damped_inverse for a square one of 2 or 3 joints), then eq. (35)-(37)'s
  ``qdot_r = J^# r``, ``qddot_r = J^# (rdot - Jdot qdot_r)`` and ``N = I - J^# J``;
- :func:`effort`: eq. (5) in joint space,
  ``tau = Y_q theta_hat + tau_0 + J^T (f - K_D e) + J_w^T (m - K_w e_w) - k_null N^T N s``;
- :func:`adapt`: eq. (26), ``theta_hat - dt Gamma^-1 Y_q^T (k_a w s)`` clipped to the box,
  with w adaptation.adaptation_weight's saturation and dead zone.

The signatures are explicit (float64, any layout), so numba compiles every kernel when this
module is imported, at configure (``cache=True``: once per install, then loaded from
``__pycache__``), never in a tick: a call with other types raises TypeError instead of
compiling. No scipy (numba's ``@`` needs it): the products are loops, on matrices of 7 x 6 at
most. ``nogil``: a tick holds no lock while it computes.
"""
from __future__ import annotations

import math

import numba as nb
from numba import boolean, float64, int64, void
import numpy as np

__all__ = ['adapt', 'effort', 'task_reference']

_A2, _A1 = float64[:, :], float64[:]
_OPTS = {'cache': True, 'nogil': True}


@nb.njit(nogil=True)
def _mul(A, B, b_transposed):
    """Return ``A B`` (``A B^T`` with ``b_transposed``)."""
    n, k = A.shape
    p = B.shape[0] if b_transposed else B.shape[1]
    out = np.empty((n, p))
    for i in range(n):
        for j in range(p):
            acc = 0.0
            for m in range(k):
                acc += A[i, m] * (B[j, m] if b_transposed else B[m, j])
            out[i, j] = acc
    return out


@nb.njit(nogil=True)
def _spd_inverse(A):
    """Return ``A^-1`` of a symmetric A by Cholesky, and False when A is not positive definite."""
    m = A.shape[0]
    L = np.zeros((m, m))
    out = np.zeros((m, m))
    for j in range(m):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:
            return out, False
        L[j, j] = math.sqrt(d)
        for i in range(j + 1, m):
            acc = A[i, j]
            for k in range(j):
                acc -= L[i, k] * L[j, k]
            L[i, j] = acc / L[j, j]
    Li = np.zeros((m, m))  # L^-1, lower triangular
    for i in range(m):
        Li[i, i] = 1.0 / L[i, i]
        for j in range(i):
            acc = 0.0
            for k in range(j, i):
                acc -= L[i, k] * Li[k, j]
            Li[i, j] = acc / L[i, i]
    for i in range(m):  # A^-1 = L^-T L^-1
        for j in range(i, m):
            acc = 0.0
            for k in range(j, m):
                acc += Li[k, i] * Li[k, j]
            out[i, j] = acc
            out[j, i] = acc
    return out, True


@nb.njit(nogil=True)
def _sigma_min_sq_bound(J):
    """linalg.sigma_min_sq_bound: ``1 / tr((J J^T)^-1)`` (3 rows: closed form); 0 if singular."""
    G = _mul(J, J, True)
    if G.shape[0] == 3:
        a, b, c, e, f, i = G[0, 0], G[0, 1], G[0, 2], G[1, 1], G[1, 2], G[2, 2]
        minors = (e * i - f * f) + (a * i - c * c) + (a * e - b * b)
        det = a * (e * i - f * f) - b * (b * i - f * c) + c * (b * f - e * c)
        return max(det, 0.0) / minors if minors > 0.0 else 0.0
    G_inv, ok = _spd_inverse(G)
    if not ok:
        return 0.0
    tr = 0.0
    for i in range(G.shape[0]):
        tr += G_inv[i, i]
    return 1.0 / tr if tr > 0.0 else 0.0


@nb.njit(nogil=True)
def _sigma_min_sq(J):
    """linalg.sigma_min_sq of a 2 x 2 or 3 x 3 J (3 x 3: the eigenvalue's closed form)."""
    if J.shape[0] == 2:
        a, b, c, d = J[0, 0], J[0, 1], J[1, 0], J[1, 1]
        det, F = a * d - b * c, a * a + b * b + c * c + d * d
        den = F + math.sqrt(max(F * F - 4.0 * det * det, 0.0))
        return 2.0 * det * det / (den if den != 0.0 else 1.0)
    G = _mul(J, J, True)
    p1 = G[0, 1] ** 2 + G[0, 2] ** 2 + G[1, 2] ** 2
    q = (G[0, 0] + G[1, 1] + G[2, 2]) / 3.0
    if p1 == 0.0:
        return min(G[0, 0], G[1, 1], G[2, 2])
    p = math.sqrt(((G[0, 0] - q) ** 2 + (G[1, 1] - q) ** 2 + (G[2, 2] - q) ** 2 + 2.0 * p1) / 6.0)
    B = (G - q * np.eye(3)) / p
    det_b = (B[0, 0] * (B[1, 1] * B[2, 2] - B[1, 2] * B[2, 1])
             - B[0, 1] * (B[1, 0] * B[2, 2] - B[1, 2] * B[2, 0])
             + B[0, 2] * (B[1, 0] * B[2, 1] - B[1, 1] * B[2, 0]))
    phi = math.acos(min(max(det_b / 2.0, -1.0), 1.0)) / 3.0
    return q + 2.0 * p * math.cos(phi + 2.0 * math.pi / 3.0)


@nb.njit(nogil=True)
def _small_inverse(A):
    """linalg.small_inverse of a 2 x 2 or 3 x 3 A (adjugate / det); False when det is 0."""
    out = np.empty(A.shape)
    if A.shape[0] == 2:
        a, b, c, d = A[0, 0], A[0, 1], A[1, 0], A[1, 1]
        det = a * d - b * c
        if det == 0.0:
            return out, False
        out[0, 0], out[0, 1], out[1, 0], out[1, 1] = d / det, -b / det, -c / det, a / det
        return out, True
    a, b, c, d, e, f, g, h, i = (A[0, 0], A[0, 1], A[0, 2], A[1, 0], A[1, 1], A[1, 2],
                                 A[2, 0], A[2, 1], A[2, 2])
    out[0, 0], out[0, 1], out[0, 2] = e * i - f * h, c * h - b * i, b * f - c * e
    out[1, 0], out[1, 1], out[1, 2] = f * g - d * i, a * i - c * g, c * d - a * f
    out[2, 0], out[2, 1], out[2, 2] = d * h - e * g, b * g - a * h, a * e - b * d
    det = a * out[0, 0] + b * out[1, 0] + c * out[2, 0]
    if det == 0.0:
        return out, False
    return out / det, True


@nb.njit(nogil=True)
def _inverse(M_inv, J, sigma0):
    """Return J^# and 1 when damped, 0 when not, -1 at a singular matrix (the module's list)."""
    m, n = J.shape
    if n > m:  # task_inverse.redundant_inverse
        JM = _mul(J, M_inv, False)
        A = _mul(JM, J, True)
        mu2 = sigma0 * sigma0 - _sigma_min_sq_bound(J) if sigma0 > 0.0 else 0.0
        if mu2 > 0.0:
            tr = 0.0
            for i in range(n):
                tr += M_inv[i, i]
            for i in range(m):
                A[i, i] += mu2 * tr / n
        A_inv, ok = _spd_inverse(A)
        state = (1 if mu2 > 0.0 else 0) if ok else -1
        return _mul(np.ascontiguousarray(JM.T), A_inv, False), state
    mu2 = sigma0 * sigma0 - _sigma_min_sq(J)  # linalg.damped_inverse
    if mu2 <= 0.0:
        J_inv, ok = _small_inverse(J)
        return J_inv, 0 if ok else -1
    JJt = _mul(J, J, True)
    for i in range(m):
        JJt[i, i] += mu2
    JJt_inv, ok = _small_inverse(JJt)
    return _mul(np.ascontiguousarray(J.T), JJt_inv, False), 1 if ok else -1


@nb.njit(int64(_A2, _A2, _A2, _A1, _A1, float64, _A2, _A2, _A1, _A1), **_OPTS)
def task_reference(M_inv, J, Jdot, r, rdot, sigma0, J_inv_out, N_out, qdot_r, qddot_r):
    """
    Fill ``J^#, N, qdot_r, qddot_r``; return the inverse's state (1 damped, 0 not, -1 singular).

    ``M_inv`` is read only for a redundant J (pass any array for a square one); ``N_out`` is
    left as it is for a square J (pass an empty one).
    """
    m, n = J.shape
    J_inv, state = _inverse(M_inv, J, sigma0)
    J_inv_out[:, :] = J_inv
    for i in range(n):
        acc = 0.0
        for k in range(m):
            acc += J_inv[i, k] * r[k]
        qdot_r[i] = acc
    a = rdot.copy()
    for k in range(m):
        for j in range(n):
            a[k] -= Jdot[k, j] * qdot_r[j]
    for i in range(n):
        acc = 0.0
        for k in range(m):
            acc += J_inv[i, k] * a[k]
        qddot_r[i] = acc
    if n > m:
        for i in range(n):
            for j in range(n):
                acc = 0.0
                for k in range(m):
                    acc += J_inv[i, k] * J[k, j]
                N_out[i, j] = (1.0 if i == j else 0.0) - acc
    return state


@nb.njit(boolean(_A2, _A1, _A1, _A2, _A1, _A2, _A1, _A2, _A1, float64, _A1), **_OPTS)
def effort(Y_q, theta_hat, tau_0, J_ee, f_minus_KDe, J_w, m_minus_Kwew, N, s, k_null, tau):
    """
    Fill ``tau`` with eq. (5)'s effort; return whether every entry is finite.

    ``tau_0`` empty: no known part; ``J_w`` with no rows: the translational task; ``N`` empty:
    a square arm. ``f_minus_KDe = f - K_D e`` and ``m_minus_Kwew = m - K_w e_w`` (3-vectors).
    """
    n = Y_q.shape[0]
    for i in range(n):
        acc = 0.0
        for k in range(Y_q.shape[1]):
            acc += Y_q[i, k] * theta_hat[k]
        for k in range(J_ee.shape[0]):
            acc += J_ee[k, i] * f_minus_KDe[k]
        for k in range(J_w.shape[0]):
            acc += J_w[k, i] * m_minus_Kwew[k]
        if tau_0.shape[0]:
            acc += tau_0[i]
        tau[i] = acc
    if N.shape[0]:
        Ns = np.zeros(n)
        for i in range(n):
            for j in range(n):
                Ns[i] += N[i, j] * s[j]
        for i in range(n):
            acc = 0.0
            for j in range(n):
                acc += N[j, i] * Ns[j]
            tau[i] -= k_null * acc
    finite = True
    for i in range(n):
        finite = finite and math.isfinite(tau[i])
    return finite


@nb.njit(void(_A1, _A2, _A2, _A1, _A1, float64, float64, float64, float64, _A1, _A1, _A1),
         **_OPTS)
def adapt(theta_hat, Gamma_inv, Y_q, s, e, k_a, error_limit, dead_zone, dt, lo, hi, out):
    """Fill ``out`` with eq. (26)'s next theta_hat (adaptation.adapt_theta, its weight w)."""
    e_norm = 0.0
    for x in e:
        e_norm += x * x
    e_norm = math.sqrt(e_norm)
    if e_norm <= dead_zone:
        w = 0.0
    else:
        w = 1.0 if e_norm <= error_limit else error_limit / e_norm
        w = w * (1.0 - dead_zone / e_norm) if dead_zone > 0.0 else w
    p, n = Y_q.shape[1], Y_q.shape[0]
    g = np.zeros(p)  # Y_q^T (k_a w s)
    for j in range(n):
        v = k_a * (s[j] * w)
        for k in range(p):
            g[k] += v * Y_q[j, k]
    for i in range(p):
        acc = 0.0
        for k in range(p):
            acc += Gamma_inv[i, k] * g[k]
        out[i] = min(max(theta_hat[i] - dt * acc, lo[i]), hi[i])
