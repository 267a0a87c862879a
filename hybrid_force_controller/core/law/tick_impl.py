"""
The law's per-tick arithmetic, in Python (the reference) or compiled (``tick_impl``).

Three steps of control_law.step, the same interface in both: :meth:`joint_reference` (the
task inverse and the joint reference, eqs. (35)-(37)), :meth:`effort` (eq. 5 in joint space)
and :meth:`adapt` (eq. 26). ``PythonTick`` is numpy, as the law was written;
``CompiledTick`` calls kernels.py, imported (compiled on the first start, then loaded from
its cache) when it is built, at configure, never in a tick; it allocates each output and the
kernel fills it. No state: the law holds it.

``CompiledTick`` also has the law's steady step in two calls (:meth:`CompiledTick.law_step`,
step_kernels.py; ``fused``), and hands out the reference's kernel (``reference_rows``) and the
stiffness estimate's (``stiffness_kernels``), which the runtime gives to those objects;
``PythonTick`` has None of them, so the numpy and Python code runs.
"""
from __future__ import annotations

import contextlib
import importlib
import math
from pathlib import Path
import time
from typing import Callable

import numpy as np

from .adaptation import adapt_theta, adaptation_weight
from .task_inverse import redundant_inverse
from ..config.groups import TICK_IMPLS
from ..model.linalg import damped_inverse

__all__ = ['TICK_IMPLS', 'CompiledTick', 'PythonTick', 'kernels_cached', 'make_tick']

_EMPTY1, _EMPTY2 = np.zeros(0), np.zeros((0, 0))
_NO_ROWS = np.zeros((0, 1))


class PythonTick:
    """The numpy reference (task_inverse.py, linalg.py, adaptation.py)."""

    name = 'python'
    fused = False  # no law_step: control_law.step runs its numpy steps
    steady_steps = 0  # the steps law_step ran (CompiledTick)
    reference_rows = None  # the reference's kernel (CompiledTick; reference.BlendedReference)
    stiffness_kernels = None  # the stiffness estimate's (CompiledTick; stiffness_compiled.py)

    def __init__(self, n_joints: int) -> None:
        self._eye_n = np.eye(n_joints)
        self.note = 'tick_impl python: the numpy reference'  # what the node logs at configure

    def joint_reference(self, M_inv: Callable[[], np.ndarray], J: np.ndarray, Jdot: np.ndarray,
                        r: np.ndarray, rdot: np.ndarray, sigma0: float) -> tuple:
        """
        Return ``J^#, N, qdot_r, qddot_r, damped`` (N None for a square J).

        ``M_inv()`` gives the inertia's inverse (called only for a redundant J).
        """
        if J.shape[1] > J.shape[0]:
            J_pinv, N, damped = redundant_inverse(M_inv(), J, sigma0, self._eye_n)
        else:
            (J_pinv, damped), N = damped_inverse(J, sigma0), None
        qdot_r = J_pinv.dot(r)
        return J_pinv, N, qdot_r, J_pinv.dot(rdot - Jdot.dot(qdot_r)), damped

    @staticmethod
    def effort(Y_q: np.ndarray, theta_hat: np.ndarray, tau_0: np.ndarray | None,
               J_ee: np.ndarray, f_minus_KDe: np.ndarray, J_w: np.ndarray | None,
               m_minus_Kwew: np.ndarray | None, N: np.ndarray | None, s: np.ndarray,
               k_null: float) -> tuple[np.ndarray, bool]:
        """Return eq. (5)'s tau and whether it is finite (None: a term that is absent)."""
        tau = Y_q.dot(theta_hat) + J_ee.T.dot(f_minus_KDe)
        if J_w is not None:
            tau += J_w.T.dot(m_minus_Kwew)
        if tau_0 is not None:
            tau += tau_0
        if N is not None:  # null-space posture damping
            tau -= k_null * N.T.dot(N.dot(s))
        return tau, math.isfinite(sum(tau.tolist()))

    def warm_up(self, model) -> None:
        """Run each step once on ``model``'s arrays (nothing to warm in Python)."""

    @staticmethod
    def adapt(theta_hat: np.ndarray, Gamma_inv: np.ndarray, Y_q: np.ndarray, s: np.ndarray,
              e: np.ndarray, k_a: float, error_limit: float, dead_zone: float, dt: float,
              lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """Return eq. (26)'s next theta_hat, s weighted by adaptation_weight(e)."""
        w = adaptation_weight(e, error_limit, dead_zone)
        return adapt_theta(theta_hat, Gamma_inv, Y_q, k_a * (s * w), dt, lo, hi)


class CompiledTick(PythonTick):
    """
    The same three steps in kernels.py (numba); raises ImportError without numba.

    And the law's steady step in two calls (:meth:`law_step`, step_kernels.py).
    """

    name = 'compiled'
    fused = True

    def __init__(self, n_joints: int) -> None:
        super().__init__(n_joints)
        t0 = time.perf_counter()
        self._k = importlib.import_module(f'{__package__}.kernels')
        self._s = importlib.import_module(f'{__package__}.step_kernels')
        self.reference_rows = self._s.reference_rows
        self.stiffness_kernels = sk = importlib.import_module(f'{__package__}.stiffness_kernels')
        compiled = any(f.stats.cache_misses for f in (
            self._k.task_reference, self._k.effort, self._k.adapt, self._s.law_front,
            self._s.law_back, self._s.reference_rows, sk.update, sk.k_s_command))
        self.note = (f"tick_impl compiled: numba kernels {'compiled' if compiled else 'loaded'}"
                     f' in {time.perf_counter() - t0:.2f} s')

    def warm_up(self, model) -> None:
        """
        Call every kernel once on ``model``'s arrays, at q = 0.

        Numba finishes a loaded kernel's code on its first call (7.6 ms measured, and a tick of
        9-18 ms in the bench before this), which must not be a tick's.
        """
        q = np.zeros(model.n)
        kin = model.kinematics(q, q)
        Y_q, tau_0 = model.regressor_affine(q, q, q, q)
        theta = np.array(model.theta_nominal, dtype=float)
        for J, Jdot, J_w in ((kin.J_ee, kin.Jdot_ee, None), (kin.J6, kin.Jdot6, kin.J_w)):
            m = J.shape[0]
            try:
                N = self.joint_reference(lambda: model.inertia_inverse(q), J, Jdot, np.zeros(m),
                                         np.zeros(m), 0.1)[1]
            except np.linalg.LinAlgError:  # a singular J at q = 0: the kernel ran all the same
                N = None
            for known in (tau_0, np.zeros(model.n)):
                self.effort(Y_q, theta, known, kin.J_ee, np.zeros(3), J_w,
                            None if J_w is None else np.zeros(3), N, q, 0.0)
        self.adapt(theta, np.eye(theta.size), Y_q, q, np.zeros(3), 1.0, 0.1, 0.0, 1e-3,
                   theta - 1.0, theta + 1.0)
        sk = self.stiffness_kernels
        st, cf = np.zeros(len(sk.STATE)), np.ones(len(sk.CONFIG))
        st[sk.STATE['_k_s']] = 1.0  # a k_s command of 1 N/m, the rest 0
        sk.update(st, cf, 1.0, 0.0, 1e-3, True)
        sk.k_s_command(st, cf, 1e-3)
        rows = np.zeros((3, 3))
        self._s.reference_rows(np.zeros((3, 3, 3)), 1.0, True, rows, 0.1, 0.0, 1.0,
                               np.zeros((2, 3)), 0.0, 1.0, np.zeros((2, 3)), rows)
        m = kin.J_ee.shape[0]
        z3 = np.zeros(3)
        with contextlib.suppress(np.linalg.LinAlgError):  # singular at q = 0: it ran all the same
            self.law_step(model, q, q, kin, (z3, z3, z3), z3[:m], np.zeros((2 * m, 2 * m + 11)),
                          (0.0, 0.0), _WarmGains(theta), np.eye(theta.size), theta, 1e-3, True)

    def joint_reference(self, M_inv: Callable[[], np.ndarray], J: np.ndarray, Jdot: np.ndarray,
                        r: np.ndarray, rdot: np.ndarray, sigma0: float) -> tuple:
        """See :meth:`PythonTick.joint_reference` (raises LinAlgError at a singular matrix)."""
        m, n = J.shape
        if n <= m and m > 3:  # a square 6 x 6 J: the reference
            return super().joint_reference(M_inv, J, Jdot, r, rdot, sigma0)
        J_pinv, qdot_r, qddot_r = np.empty((n, m)), np.empty(n), np.empty(n)
        N = np.empty((n, n)) if n > m else None
        state = self._k.task_reference(M_inv() if n > m else _EMPTY2, J, Jdot, r, rdot, sigma0,
                                       J_pinv, _EMPTY2 if N is None else N, qdot_r, qddot_r)
        if state < 0:
            raise np.linalg.LinAlgError('singular matrix (a singular pose)')
        return J_pinv, N, qdot_r, qddot_r, state == 1

    def effort(self, Y_q: np.ndarray, theta_hat: np.ndarray, tau_0: np.ndarray | None,
               J_ee: np.ndarray, f_minus_KDe: np.ndarray, J_w: np.ndarray | None,
               m_minus_Kwew: np.ndarray | None, N: np.ndarray | None, s: np.ndarray,
               k_null: float) -> tuple[np.ndarray, bool]:
        """See :meth:`PythonTick.effort`."""
        tau = np.empty(Y_q.shape[0])
        finite = self._k.effort(Y_q, theta_hat, _EMPTY1 if tau_0 is None else tau_0, J_ee,
                                f_minus_KDe, _NO_ROWS if J_w is None else J_w,
                                _EMPTY1 if m_minus_Kwew is None else m_minus_Kwew,
                                _EMPTY2 if N is None else N, s, k_null, tau)
        return tau, finite

    def adapt(self, theta_hat: np.ndarray, Gamma_inv: np.ndarray, Y_q: np.ndarray,
              s: np.ndarray, e: np.ndarray, k_a: float, error_limit: float, dead_zone: float,
              dt: float, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        """See :meth:`PythonTick.adapt`."""
        out = np.empty(theta_hat.shape[0])
        self._k.adapt(theta_hat, Gamma_inv, Y_q, s, e, k_a, error_limit, dead_zone, dt, lo, hi,
                      out)
        return out

    def law_step(self, model, q: np.ndarray, qdot: np.ndarray, kin, ref, f: np.ndarray,
                 G: np.ndarray, r_n_rdot_n: tuple[float, float], gains, Gamma_inv: np.ndarray,
                 theta_hat: np.ndarray, dt: float, adapt: bool) -> tuple:
        """
        Run the law's steady step (step_kernels.py); return ``tau, e, theta, damped``.

        ``tau`` None: not finite; ``theta`` None: nothing adapted (``dt`` 0, ``adapt`` False, or
        a damped inverse). Raises LinAlgError at a singular matrix.
        """
        self.steady_steps += 1
        J = kin.J_ee
        m, n = J.shape
        rr, e, J_inv = np.empty(2 * m), np.empty(m), np.empty((n, m))
        qdot_r, qddot_r, V = np.empty(n), np.empty(n), np.empty((2, n))
        N = np.empty((n, n)) if n > m else _EMPTY2
        state = self._s.law_front(G, kin.x, kin.xdot, *ref, *r_n_rdot_n, J, kin.Jdot_ee,
                                  model.inertia_inverse(q) if n > m else _EMPTY2,
                                  gains.singular_sigma, qdot, rr, e, J_inv, N, qdot_r, qddot_r, V)
        if state < 0:
            raise np.linalg.LinAlgError('singular matrix (a singular pose)')
        P, known = model.regressor_map
        tau, theta = np.empty(n), np.empty(theta_hat.size)
        dt_adapt = dt if adapt and state == 0 else 0.0
        finite = self._s.law_back(*model.regressor_pair(q, V, qddot_r), P, known, theta_hat, J,
                                  f, gains.k_d, e, N, qdot, qdot_r, gains.k_null, Gamma_inv,
                                  gains.k_a, gains.adapt_error_limit, gains.adapt_dead_zone,
                                  dt_adapt, gains.theta_min, gains.theta_max, tau, theta)
        return (tau if finite else None), e, (theta if dt_adapt > 0.0 else None), state == 1


class _WarmGains:
    """The gains law_step reads, for warm_up (any values run every kernel)."""

    def __init__(self, theta: np.ndarray) -> None:
        self.singular_sigma, self.k_d, self.k_null, self.k_a = 0.1, 1.0, 0.0, 1.0
        self.adapt_error_limit, self.adapt_dead_zone = 0.1, 0.0
        self.theta_min, self.theta_max = theta - 1.0, theta + 1.0


def kernels_cached() -> bool:
    """Say whether the kernels' compiled code looks cached beside them (else: a first compile)."""
    cache = Path(__file__).parent / '__pycache__'
    return all(any(cache.glob(f'{name}.*.nbi'))
               for name in ('kernels', 'step_kernels', 'stiffness_kernels'))


def make_tick(impl: str, n_joints: int) -> PythonTick:
    """
    Return the tick of ``impl`` (one of :data:`TICK_IMPLS`) for an arm of ``n_joints``.

    ``compiled`` without numba importable runs the reference, and its ``note`` says so.
    """
    if impl not in TICK_IMPLS:
        raise ValueError(f'tick_impl must be one of {list(TICK_IMPLS)}, got {impl!r}')
    if impl == 'python':
        return PythonTick(n_joints)
    try:
        return CompiledTick(n_joints)
    except ImportError as exc:
        tick = PythonTick(n_joints)
        tick.note = (f'tick_impl compiled: numba is not importable ({exc}): the Python '
                     'reference runs (pip install numba, or apt install python3-numba)')
        return tick
