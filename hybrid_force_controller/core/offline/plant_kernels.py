r"""
The paper's plant compiled (numba): one :class:`~.simulator.ArmSimulator` step in one call.

:func:`step` is the simulator's step (``plant_impl: compiled``): for each of its sub-steps of
``h``, the tool's pose and Jacobian, the surface's spring ``f = k depth n(p)`` (eqs. (12)-(13),
environment.py's plane, sphere and cylinder) and its joint torque ``-J_pᵀ f``, the joint
friction ``b q̇ + f_c tanh(q̇ / 1e-3)``, the articulated-body algorithm (Featherstone's ABA, as
pinocchio's ``aba``), then ``q̇ += h q̈``, ``q += h q̇``; at the end the sensors' pose and force.
:func:`contact` is that last part alone. The model is a tree of one-DOF joints, revolute or
prismatic, in pinocchio's conventions (motion ``[v; ω]``, force ``[f; n]``, each joint's frame
``placement · joint(q)``), held in the arrays :func:`~.plant_compiled.plant_arrays` builds:

- ``ji`` (int64): each joint's parent (-1: the root), then each joint's kind (0 revolute,
  1 prismatic), then the tool frame's joint;
- ``jf`` (n × 51): each joint's axis (3), its placement's rotation (9, row-major) and
  translation (3), and its spatial inertia at its origin (36, row-major);
- ``cf`` (27): gravity in the root frame (3), the tool frame's placement in its joint
  (rotation 9, translation 3), the base frame's rotation from the root (9) and the root's
  origin (3) (``robot_model.base_from_root``);
- ``sf`` (15): the surface: its shape (0 none, 1 plane, 2 sphere, 3 cylinder), k, x0, n,
  radius, centre, axis.

Same formulas as the Python step; only the order of the sums differs, so the two agree to
rounding (test_plant_impl). Explicit signatures: compiled at import (``cache=True``); each call
writes into arrays its caller allocated (nothing boxed on the way out).
"""
from __future__ import annotations

import math

import numba as nb
from numba import float64, int64, void
import numpy as np

__all__ = ['contact', 'step']

_A1, _A2, _I1 = float64[:], float64[:, :], int64[:]
_OPTS = {'cache': True, 'nogil': True}


@nb.njit(nogil=True)
def _kinematics(ji, jf, q, oR, op, lR, lp):
    """Each joint's placement in its parent (``lR``, ``lp``) and in the root (``oR``, ``op``)."""
    n = q.shape[0]
    for i in range(n):
        a0, a1, a2 = jf[i, 0], jf[i, 1], jf[i, 2]
        if ji[n + i] == 0:  # revolute: placement · R(a, q), R = c I + s [a]x + (1 - c) a a^T
            c, s = math.cos(q[i]), math.sin(q[i])
            d = 1.0 - c
            r00, r01, r02 = d * a0 * a0 + c, d * a0 * a1 - s * a2, d * a0 * a2 + s * a1
            r10, r11, r12 = d * a1 * a0 + s * a2, d * a1 * a1 + c, d * a1 * a2 - s * a0
            r20, r21, r22 = d * a2 * a0 - s * a1, d * a2 * a1 + s * a0, d * a2 * a2 + c
            for r in range(3):
                P0, P1, P2 = jf[i, 3 + 3 * r], jf[i, 4 + 3 * r], jf[i, 5 + 3 * r]
                lR[i, r, 0] = P0 * r00 + P1 * r10 + P2 * r20
                lR[i, r, 1] = P0 * r01 + P1 * r11 + P2 * r21
                lR[i, r, 2] = P0 * r02 + P1 * r12 + P2 * r22
                lp[i, r] = jf[i, 12 + r]
        else:  # prismatic: the placement, then a translation q a
            for r in range(3):
                P0, P1, P2 = jf[i, 3 + 3 * r], jf[i, 4 + 3 * r], jf[i, 5 + 3 * r]
                lR[i, r, 0], lR[i, r, 1], lR[i, r, 2] = P0, P1, P2
                lp[i, r] = jf[i, 12 + r] + q[i] * (P0 * a0 + P1 * a1 + P2 * a2)
        p = ji[i]
        for r in range(3):
            if p < 0:
                op[i, r] = lp[i, r]
                for k in range(3):
                    oR[i, r, k] = lR[i, r, k]
                continue
            op[i, r] = op[p, r] + (oR[p, r, 0] * lp[i, 0] + oR[p, r, 1] * lp[i, 1]
                                   + oR[p, r, 2] * lp[i, 2])
            for k in range(3):
                oR[i, r, k] = (oR[p, r, 0] * lR[i, 0, k] + oR[p, r, 1] * lR[i, 1, k]
                               + oR[p, r, 2] * lR[i, 2, k])


@nb.njit(nogil=True)
def _tool(ji, jf, cf, oR, op, p_W, R_W, J_W, T):
    """
    Write the tool frame's position, rotation and linear Jacobian, in the base frame.

    The Jacobian is pinocchio's LOCAL_WORLD_ALIGNED one at the frame's origin: a revolute
    joint's column ``a_o × (p - p_j)``, a prismatic one's ``a_o``; then
    robot_model.base_from_root. ``T``: a 3 × 3 workspace.
    """
    n = J_W.shape[1]
    fj = ji[2 * n]
    for r in range(3):  # the frame in the root: T, (p0, p1, p2) via p_W
        for k in range(3):
            T[r, k] = cf[3 + 3 * r + k] if fj < 0 else (
                oR[fj, r, 0] * cf[3 + k] + oR[fj, r, 1] * cf[6 + k] + oR[fj, r, 2] * cf[9 + k])
        p_W[r] = cf[12 + r] if fj < 0 else op[fj, r] + (
            oR[fj, r, 0] * cf[12] + oR[fj, r, 1] * cf[13] + oR[fj, r, 2] * cf[14])
    p0, p1, p2 = p_W[0], p_W[1], p_W[2]
    J_W[:, :] = 0.0
    j = fj
    while j >= 0:
        ax = oR[j, 0, 0] * jf[j, 0] + oR[j, 0, 1] * jf[j, 1] + oR[j, 0, 2] * jf[j, 2]
        ay = oR[j, 1, 0] * jf[j, 0] + oR[j, 1, 1] * jf[j, 1] + oR[j, 1, 2] * jf[j, 2]
        az = oR[j, 2, 0] * jf[j, 0] + oR[j, 2, 1] * jf[j, 1] + oR[j, 2, 2] * jf[j, 2]
        if ji[n + j] == 0:
            d0, d1, d2 = p0 - op[j, 0], p1 - op[j, 1], p2 - op[j, 2]
            ax, ay, az = ay * d2 - az * d1, az * d0 - ax * d2, ax * d1 - ay * d0
        for r in range(3):
            J_W[r, j] = cf[15 + 3 * r] * ax + cf[16 + 3 * r] * ay + cf[17 + 3 * r] * az
        j = ji[j]
    d0, d1, d2 = p0 - cf[24], p1 - cf[25], p2 - cf[26]
    for r in range(3):
        b0, b1, b2 = cf[15 + 3 * r], cf[16 + 3 * r], cf[17 + 3 * r]
        p_W[r] = b0 * d0 + b1 * d1 + b2 * d2
        for k in range(3):
            R_W[r, k] = b0 * T[0, k] + b1 * T[1, k] + b2 * T[2, k]


@nb.njit(nogil=True)
def _spring(sf, p, f):
    """
    Write the force the tool exerts on the surface, ``k depth n(p)`` (0 unless depth > 0).

    Eqs. (12)-(13) on the plane; along the local normal on a sphere or cylinder
    (environment.py).
    """
    shape, k, radius = sf[0], sf[1], sf[8]
    f[:] = 0.0
    if shape == 0.0:
        return
    if shape == 1.0:
        depth = (sf[5] * (p[0] - sf[2]) + sf[6] * (p[1] - sf[3])) + sf[7] * (p[2] - sf[4])
        if depth <= 0.0:
            return
        for r in range(3):
            f[r] = (k * depth) * sf[5 + r]
        return
    x, y, z = p[0] - sf[9], p[1] - sf[10], p[2] - sf[11]
    if shape == 3.0:  # the cylinder: perpendicular to its axis
        d = (x * sf[12] + y * sf[13]) + z * sf[14]
        x, y, z = x - d * sf[12], y - d * sf[13], z - d * sf[14]
    dist = math.sqrt((x * x + y * y) + z * z)
    depth = radius - dist
    if depth <= 0.0:
        return
    if not dist > 1e-12 * radius:  # at the centre: n_W
        for r in range(3):
            f[r] = (k * depth) * sf[5 + r]
        return
    f[0], f[1], f[2] = ((k * depth) * (x * (-1.0 / dist)), (k * depth) * (y * (-1.0 / dist)),
                        (k * depth) * (z * (-1.0 / dist)))


@nb.njit(nogil=True)
def _motion_in_child(lR, lp, i, m, out):
    """``out`` = the motion ``m`` (parent frame) in child ``i``: ``[Rᵀ(v - t × ω); Rᵀ ω]``."""
    w0, w1, w2 = m[3], m[4], m[5]
    v0 = m[0] - (lp[i, 1] * w2 - lp[i, 2] * w1)
    v1 = m[1] - (lp[i, 2] * w0 - lp[i, 0] * w2)
    v2 = m[2] - (lp[i, 0] * w1 - lp[i, 1] * w0)
    for r in range(3):
        out[r] = lR[i, 0, r] * v0 + lR[i, 1, r] * v1 + lR[i, 2, r] * v2
        out[3 + r] = lR[i, 0, r] * w0 + lR[i, 1, r] * w1 + lR[i, 2, r] * w2


@nb.njit(nogil=True)
def _cross_motion(m, u, out):
    """``out`` = ``m ×ₘ u`` = ``[ω × u_v + v × u_ω; ω × u_ω]``."""
    for r in range(3):
        a, b = (r + 1) % 3, (r + 2) % 3
        out[r] = (m[3 + a] * u[b] - m[3 + b] * u[a]) + (m[a] * u[3 + b] - m[b] * u[3 + a])
        out[3 + r] = m[3 + a] * u[3 + b] - m[3 + b] * u[3 + a]


@nb.njit(nogil=True)
def _cross_force(m, f, out):
    """``out`` = ``m ×* f`` = ``[ω × f; ω × n + v × f]``."""
    for r in range(3):
        a, b = (r + 1) % 3, (r + 2) % 3
        out[r] = m[3 + a] * f[b] - m[3 + b] * f[a]
        out[3 + r] = (m[3 + a] * f[3 + b] - m[3 + b] * f[3 + a]) + (m[a] * f[b] - m[b] * f[a])


@nb.njit(nogil=True)
def _force_to_parent(lR, lp, i, X):
    """Write the 6 × 6 map of a force from child ``i`` to its parent: ``[[R, 0], [[t]x R, R]]``."""
    X[:, :] = 0.0
    for r in range(3):
        for k in range(3):
            X[r, k] = X[3 + r, 3 + k] = lR[i, r, k]
    for k in range(3):
        X[3, k] = lp[i, 1] * lR[i, 2, k] - lp[i, 2] * lR[i, 1, k]
        X[4, k] = lp[i, 2] * lR[i, 0, k] - lp[i, 0] * lR[i, 2, k]
        X[5, k] = lp[i, 0] * lR[i, 1, k] - lp[i, 1] * lR[i, 0, k]


@nb.njit(nogil=True)
def _matvec(A, x, out):
    """``out`` = ``A x`` (loops: numba's ``@`` needs scipy)."""
    for r in range(A.shape[0]):
        acc = 0.0
        for k in range(A.shape[1]):
            acc += A[r, k] * x[k]
        out[r] = acc


@nb.njit(nogil=True)
def _dot(x, y):
    acc = 0.0
    for k in range(x.shape[0]):
        acc += x[k] * y[k]
    return acc


@nb.njit(nogil=True)
def _to_parent(X, A, B, XA):
    """``B += X A Xᵀ`` (6 × 6; ``XA`` a workspace)."""
    for r in range(6):
        for k in range(6):
            acc = 0.0
            for m in range(6):
                acc += X[r, m] * A[m, k]
            XA[r, k] = acc
    for r in range(6):
        for k in range(6):
            acc = 0.0
            for m in range(6):
                acc += XA[r, m] * X[k, m]
            B[r, k] += acc


@nb.njit(nogil=True)
def _aba_velocities(ji, jf, lR, lp, qdot, W, Ia):
    """
    Compute pass 1 of ABA: the velocities, their products and the bias forces.

    ``v_i = X_i v_λ + S_i q̇_i``, ``c_i = v_i ×ₘ S_i q̇_i``, ``p_i = v_i ×* I_i v_i``.
    """
    n = qdot.shape[0]
    S, v, c, pA, w6 = W[0], W[1], W[2], W[3], W[7, 0]
    S[:, :] = 0.0
    W[1, n, :] = 0.0  # the root's velocity
    for i in range(n):
        off = 0 if ji[n + i] == 1 else 3
        for r in range(3):
            S[i, off + r] = jf[i, r]
        p = ji[i] if ji[i] >= 0 else n
        _motion_in_child(lR, lp, i, v[p], v[i])
        for r in range(6):
            w6[r] = S[i, r] * qdot[i]
            v[i, r] += w6[r]
        _cross_motion(v[i], w6, c[i])
        for r in range(6):
            for k in range(6):
                Ia[i, r, k] = jf[i, 15 + 6 * r + k]
        _matvec(Ia[i], v[i], w6)
        _cross_force(v[i], w6, pA[i])


@nb.njit(nogil=True)
def _aba(ji, jf, cf, lR, lp, qdot, tau, qdd, W, Ia, X):
    """
    Write ``q̈`` of ``M(q) q̈ + C(q, q̇) q̇ + g(q) = τ`` (ABA; ``lR``, ``lp`` at q).

    Pass 1 (:func:`_aba_velocities`); pass 2: the articulated inertias and biases, child to
    parent; pass 3: ``a_i = X_i a_λ + c_i`` from ``a_0 = -g``, ``q̈_i = (u_i - U_iᵀ a_i) / D_i``.
    Workspaces: ``W`` (8, n + 1, 6), ``Ia`` (n, 6, 6), ``X`` (2, 6, 6).
    """
    n = qdot.shape[0]
    _aba_velocities(ji, jf, lR, lp, qdot, W, Ia)
    S, c, pA, U, a, Du, w6 = W[0], W[2], W[3], W[4], W[5], W[6], W[7, 0]
    for i in range(n - 1, -1, -1):
        _matvec(Ia[i], S[i], U[i])
        Du[i, 0] = _dot(S[i], U[i])
        Du[i, 1] = tau[i] - _dot(S[i], pA[i])
        p = ji[i]
        if p < 0:
            continue
        for r in range(6):
            for k in range(6):
                Ia[i, r, k] -= U[i, r] * U[i, k] / Du[i, 0]
        _matvec(Ia[i], c[i], w6)
        for r in range(6):
            w6[r] += pA[i, r] + U[i, r] * (Du[i, 1] / Du[i, 0])
        _force_to_parent(lR, lp, i, X[0])
        _to_parent(X[0], Ia[i], Ia[p], X[1])
        for r in range(6):
            pA[p, r] += _dot(X[0, r], w6)
    for r in range(6):  # the root's acceleration: -g
        a[n, r] = -cf[r] if r < 3 else 0.0
    for i in range(n):
        p = ji[i] if ji[i] >= 0 else n
        _motion_in_child(lR, lp, i, a[p], a[i])
        for r in range(6):
            a[i, r] += c[i, r]
        qdd[i] = (Du[i, 1] - _dot(U[i], a[i])) / Du[i, 0]
        for r in range(6):
            a[i, r] += S[i, r] * qdd[i]


@nb.njit(nogil=True)
def _sense(ji, jf, cf, sf, q, K, p_W, R_W, J_W, f_W):
    """
    Compute the kinematics at q, the tool's pose and Jacobian, the surface's force.

    ``K`` (5, n, 3, 3): the joints' rotations in the root and in their parents, their origins
    (``K[2, :, 0]``, ``K[3, :, 0]``) and a 3 × 3 workspace.
    """
    op, lp = K[2, :, 0, :], K[3, :, 0, :]
    _kinematics(ji, jf, q, K[0], op, K[1], lp)
    _tool(ji, jf, cf, K[0], op, p_W, R_W, J_W, K[4, 0])
    _spring(sf, p_W, f_W)


@nb.njit(void(_I1, _A2, _A1, _A1, _A1, _A1, _A2, _A1, _A1), **_OPTS)
def contact(ji, jf, cf, sf, q, p_W, R_W, f_W, tau_c):
    """Write the tool's pose, the surface's force on it and its joint torque ``-J_pᵀ f`` at q."""
    n = q.shape[0]
    K, J = np.empty((5, n, 3, 3)), np.empty((3, n))
    _sense(ji, jf, cf, sf, q, K, p_W, R_W, J, f_W)
    for j in range(n):
        tau_c[j] = -((J[0, j] * f_W[0] + J[1, j] * f_W[1]) + J[2, j] * f_W[2])


@nb.njit(void(_I1, _A2, _A1, _A1, _A1, _A1, _A1, float64, int64, float64, float64,
              _A1, _A1, _A1, _A2, _A1), **_OPTS)
def step(ji, jf, cf, sf, q, qdot, tau, h, substeps, b, fc, q_out, qdot_out, p_W, R_W, f_W):
    """
    Write the state after ``substeps`` semi-implicit Euler steps of ``h``, and its sensors.

    Each: ``τ_net = τ - J_pᵀ f - (b q̇ + f_c tanh(q̇ / 1e-3))``, ``q̈ = ABA(q, q̇, τ_net)``,
    ``q̇ += h q̈``, ``q += h q̇`` (simulator.py ``ArmSimulator.step``).
    """
    n = q.shape[0]
    K, J, V = np.empty((5, n, 3, 3)), np.empty((3, n)), np.empty((2, n))
    W, Ia, X = np.empty((8, n + 1, 6)), np.empty((n, 6, 6)), np.empty((2, 6, 6))
    tau_net, qdd = V[0], V[1]
    q_out[:] = q
    qdot_out[:] = qdot
    for _ in range(substeps):
        _sense(ji, jf, cf, sf, q_out, K, p_W, R_W, J, f_W)
        for j in range(n):
            tau_net[j] = tau[j] + -((J[0, j] * f_W[0] + J[1, j] * f_W[1]) + J[2, j] * f_W[2])
            if b != 0.0 or fc != 0.0:
                tau_net[j] -= b * qdot_out[j] + fc * math.tanh(qdot_out[j] / 1e-3)
        _aba(ji, jf, cf, K[1], K[3, :, 0, :], qdot_out, tau_net, qdd, W, Ia, X)
        for j in range(n):
            qdot_out[j] += h * qdd[j]
            q_out[j] += h * qdot_out[j]
    _sense(ji, jf, cf, sf, q_out, K, p_W, R_W, J, f_W)
