"""
The law's r and rdot when the normal moves: S = n_hat n_hat^T with n_hat estimated (issue 24).

docs/design.md, "A moving normal", derives the rate limit (N7) and what the law must add to
rdot. This module is that, in the form the law computes (control_law.py's module docstring)::

    r    = (I - S)(xdot_d - lambda1 dx) + n r_n,
    rdot = (I - S)(xddot_d + lambda1 xdot_d) - lambda1 xdot + n rdot_n           (frozen S)

**The reference on the surface.** A user's reference (the sine, a held point, a path) lives
in the plane of the *told* normal n_p (the ``n`` parameter: a path is planned in its tangent
plane, law/path.py). With n_hat != n_p it is carried onto the tangent plane of n_hat through
the tool along n_p (:func:`project_rows`, an oblique projection)::

    Pi = I - n_p n_hat^T / (n_hat^T n_p),
    x_d' = x + Pi (x_d - x),   xdot_d' = Pi xdot_d,   xddot_d' = Pi xddot_d               (M1)

so ``(I - S)(x - x_d') = Pi (x - x_d)``: the tool is asked to be where the point of the path
is when seen along n_p (the path's own plane), on the surface as n_hat says it is, and the
reference has no part along n_hat (``d_n = 0`` in (19') of design.md: no input ``omega d_n``).

**What rdot must add.** With the reference (M1) the tangential part of r is ``u = xdot_d' +
lambda1 (x_d' - x) = Pi (xdot_d - lambda1 (x - x_d))`` and the normal part ``n_hat r_n``,
``r_n = c fdot_d - c lambda1 (n_hat^T f - f_d) - lambda2 h`` in the force loop. Their exact
derivative, with ``ndot`` the estimate's rate and ``kappa = 1 / (n_hat^T n_p)``, is::

    rdot = w + lambda1 a kappa n_p + n_hat (rdot_n - lambda1 a + dr_n)
             + r_n ndot - kappa (ndot^T u) n_p,                                          (M2)
    w = xddot_d' + lambda1 (xdot_d' - xdot),   a = n_hat^T xdot,   dr_n = d r_n / d n_hat . ndot

(``dr_n = -c lambda1 ndot^T f`` in the force loop, ``-lambda1 ndot^T x`` in an approach). The
first line is the frozen-S rdot of the projected reference (the ``lambda1 a kappa n_p`` term
makes it the derivative of ``Pi (x - x_d)`` rather than of ``(I - S)(x - x_d')``); the second
holds the terms in ndot: ``d(Pi)/dt v = -kappa (ndot^T Pi v) n_p`` and ``r_n ndot``, which
contain design.md's ``S_dot (q_dot + lambda1 q) + lambda2 ndot h`` (``lambda2 h`` is part of
``r_n``), fed forward so that (N7) is the whole condition on the rate. With ``n_hat = n_p`` and
``ndot = 0`` (M2) is the frozen-S rdot above. Pure numpy, O(1) per tick, nothing allocated
beyond a few small arrays.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ['MovingNormal', 'project_rows']


def project_rows(rows_W: np.ndarray, x_W: np.ndarray, n: Sequence[float],
                 kq: Sequence[float]) -> list[list[float]]:
    """
    Return (M1): the rows x_d, xdot_d, xddot_d carried onto n_hat's tangent plane, as lists.

    ``rows_W`` (3, 3) base frame; ``x_W`` the tool; ``n`` = n_hat (unit, 3 floats) and ``kq``
    = ``kappa n_p`` (3 floats). The rows returned have no part along n_hat (the first
    relative to ``x_W``). On floats: three 3-vectors cost less than numpy's calls.
    """
    n0, n1, n2 = n
    q0, q1, q2 = kq
    x0, x1, x2 = x_W.tolist()
    (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = rows_W.tolist()
    d = a0 * n0 + a1 * n1 + a2 * n2 - (x0 * n0 + x1 * n1 + x2 * n2)
    e = b0 * n0 + b1 * n1 + b2 * n2
    f = c0 * n0 + c1 * n1 + c2 * n2
    return [[a0 - d * q0, a1 - d * q1, a2 - d * q2], [b0 - e * q0, b1 - e * q1, b2 - e * q2],
            [c0 - f * q0, c1 - f * q1, c2 - f * q2]]


class MovingNormal:
    """
    The moving normal the law uses, and (M2); on floats, in the base frame.

    ``n`` is n_hat (unit), ``ndot`` its rate (1/s), ``n_p`` the told normal (3-tuples, base
    frame), ``kappa`` = ``1 / (n^T n_p)``; ``axes`` the task coordinates among the base axes
    (None: all three). Set by the runtime (runtime/surface.py) on every new state. ``rows``
    may hold the projected reference as lists (base frame) with ``ref`` the Reference made of
    them: the law then reads them instead of converting the arrays again. Unrolled 3-vector
    arithmetic: a dozen numpy calls on 3-vectors would cost more than the whole of it.
    """

    __slots__ = ('n', 'ndot', 'n_p', 'kappa', 'axes', 'rows', 'ref')

    def __init__(self, n: Sequence[float], ndot: Sequence[float], n_p: Sequence[float],
                 kappa: float, axes: list | None = None) -> None:
        self.n, self.ndot, self.n_p, self.kappa, self.axes = n, ndot, n_p, kappa, axes
        self.rows: list | None = None
        self.ref = None

    def _base(self, v: np.ndarray) -> list:
        """Return the task vector ``v`` as a base-frame 3-vector (zero off the task axes)."""
        if self.axes is None:
            return v.tolist()
        out = [0.0, 0.0, 0.0]
        for i, a in zip(self.axes, v.tolist()):
            out[i] = a
        return out

    def dot(self, v: np.ndarray, rate: bool = False) -> float:
        """Return ``n^T v`` (``rate``: ``ndot^T v``) for a task vector ``v``."""
        a, b, c = self._base(v)
        n0, n1, n2 = self.ndot if rate else self.n
        return n0 * a + n1 * b + n2 * c

    def r_rdot(self, x: np.ndarray, xdot: np.ndarray, ref: Sequence[np.ndarray], l1: float,
               r_n: float, rdot_n: float, dr_n: float) -> tuple[np.ndarray, np.ndarray]:
        """
        Return r and rdot (task coordinates), (M2), from the projected reference ``ref`` (M1).

        ``x``, ``xdot`` in task coordinates; ``r_n`` is the normal part of r, ``rdot_n`` the
        mode's part of rdot's normal part (as for the frozen law) and ``dr_n`` the derivative
        of r_n through n_hat.
        """
        n0, n1, n2 = self.n
        d0, d1, d2 = self.ndot
        q0, q1, q2 = self.n_p
        rows = self.rows if ref is self.ref else [v.tolist() for v in ref]
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = rows
        x0, x1, x2 = self._base(x)
        v0, v1, v2 = self._base(xdot)
        u0, u1, u2 = b0 + l1 * (a0 - x0), b1 + l1 * (a1 - x1), b2 + l1 * (a2 - x2)
        a_n = n0 * v0 + n1 * v1 + n2 * v2
        c_n = rdot_n + dr_n - l1 * a_n
        c_q = self.kappa * (l1 * a_n - (d0 * u0 + d1 * u1 + d2 * u2))
        out = np.array(((u0 + r_n * n0, u1 + r_n * n1, u2 + r_n * n2),
                        (c0 + l1 * (b0 - v0) + c_n * n0 + c_q * q0 + r_n * d0,
                         c1 + l1 * (b1 - v1) + c_n * n1 + c_q * q1 + r_n * d1,
                         c2 + l1 * (b2 - v2) + c_n * n2 + c_q * q2 + r_n * d2)))
        if self.axes is not None:
            out = out[:, self.axes]
        return out[0], out[1]
