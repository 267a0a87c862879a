"""
Delay margin of the closed loop: how much loop delay the gains tolerate (pure numpy).

A real-time loop between two processes delays every measurement by tau (state stamp to
effort applied). Linearised about a steady state with the model known, each task axis
of the law of [1] (eqs. (5), (8), (11) scaled, (26)) is a mass ``m`` (an eigenvalue of
the task inertia ``M_x``, eq. (35)) under a delayed control force:

* along the surface, ``m s^2 X = -e^{-s tau} [(m lambda1 + K_D) s + K_D lambda1
  + K_I (1 + lambda1 / s)] X``;
* along n, against a surface of stiffness k (force through the low-pass filter F(s)),
  ``(m s^2 + k) X = -e^{-s tau} [(m lambda1 + K_D) s + ((m lambda2 + K_D c lambda1 - 1) k
  + K_D lambda2 k / s) F(s) + K_I (1 + (c lambda1 k / s + lambda2 k / s^2) F(s))] X``,

where ``K_I = k_a J^-T Y_g Gamma^-1 Y_g^T J^-1`` (along the axis) is the stiffness the
adaptation (26) adds through the gravity regressor ``Y_g``. A characteristic root
crosses the imaginary axis only at a frequency where ``|G(j w)| = 1`` (``G`` the bracket
over the left side); the delay margin is the smallest ``tau`` that puts a root there:
``min_w (pi + arg G(j w) mod 2 pi) / w``. It is 0 if the loop is unstable without delay.
The margin of a gain set is the worst over both masses of the axis and over surface
stiffnesses up to ``k_max``.

With the online stiffness estimate on (stiffness_loop.py) k_s moves without a parameter
set, with ``lambda2 = lambda2_0 k_s0 / k_s``; a set is a promise for every k_s it may
command, so the margin is then also the worst over k_s on a geometric grid of
``[min(k_min, k_s0), max(k_max, k_s0)]`` against ``k = (1 + 3 tol) k_s`` (k_s falls only
to a valid estimate, whose standard deviation is at most ``tol k_s``), ``0.3 k_s`` and
``0.1 k_s`` (k_s above k while it falls).
"""
from __future__ import annotations

import dataclasses
import math
from typing import Callable

import numpy as np

from .params import LawGains
from .robot_model import RobotModel
from .stiffness import StiffnessConfig

__all__ = ['K_S_GRID', 'axis_margin', 'delay_margin', 'estimate_operating_points']

_W = np.logspace(-1.0, 4.5, 2000)  # rad/s
K_S_GRID = 5  # k_s values of the estimate's range in the margin (module docstring)


def _crossing_margin(G: Callable[[np.ndarray], np.ndarray]) -> float:
    """Smallest delay that puts a root of ``1 + e^{-s tau} G(s)`` on the imaginary axis."""
    g = G(1j * _W)
    mag = np.abs(g) - 1.0
    best = math.inf
    for i in np.flatnonzero(np.sign(mag[:-1]) != np.sign(mag[1:])):
        lo, hi = _W[i], _W[i + 1]
        for _ in range(40):  # bisection on |G| = 1 (log-spaced)
            mid = math.sqrt(lo * hi)
            if (abs(G(np.array([1j * mid]))[0]) - 1.0) * mag[i] > 0:
                lo = mid
            else:
                hi = mid
        w = math.sqrt(lo * hi)
        phase = (math.pi + float(np.angle(G(np.array([1j * w]))[0]))) % (2.0 * math.pi)
        best = min(best, phase / w)
    return best


def _cancel_s(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cancel the factors ``s`` common to both polynomials (trailing zero coefficients)."""
    while len(num) > 1 and len(den) > 1 and num[-1] == 0.0 and den[-1] == 0.0:
        num, den = num[:-1], den[:-1]
    return num, den


def _stable_without_delay(num: np.ndarray, den: np.ndarray) -> bool:
    """Roots of ``den + num`` (polynomial coefficients, highest first) in the left half."""
    n = max(len(num), len(den))
    poly = np.pad(den, (n - len(den), 0)) + np.pad(num, (n - len(num), 0))
    return bool(np.all(np.roots(poly).real < 0.0))


def axis_margin(g: LawGains, m: float, K_I: float, k: float | None = None,
                filter_hz: float = 0.0) -> float:
    """
    Delay margin (s) of one task axis of mass ``m`` (kg).

    Along the surface when ``k`` is None, else along n against a surface of stiffness ``k`` (N/m).
    """
    l1, l2, kd, c = g.lambda1, g.lambda2, g.k_d, 1.0 / g.k_s
    wf = 2.0 * math.pi * filter_hz if filter_hz > 0.0 else math.inf
    F = [1.0] if math.isinf(wf) else [1.0 / wf, 1.0]  # denominator of the filter
    B = m * l1 + kd
    if k is None:  # G s / s: num = B s^2 + (kd l1 + K_I) s + K_I l1, den = m s^3
        num = np.array([B, kd * l1 + K_I, K_I * l1])
        den = np.array([m, 0.0, 0.0, 0.0])
    else:  # G times s^2 F_den / s^2 F_den (F = 1 / F_den, the force filter)
        a = (m * l2 + kd * c * l1 - 1.0) * k
        num = np.polyadd(np.polymul([B, K_I, 0.0, 0.0], F),
                         [a, kd * l2 * k + K_I * c * l1 * k, K_I * l2 * k])
        den = np.polymul([m, 0.0, k, 0.0, 0.0], F)
    num, den = _cancel_s(np.asarray(num, dtype=float), np.asarray(den, dtype=float))
    if not _stable_without_delay(num, den):
        return 0.0
    return _crossing_margin(lambda s: np.polyval(num, s) / np.polyval(den, s))


def _axis_gains(model: RobotModel, g: LawGains, q: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Task inertia M_x, the adaptation stiffness K_I and the normal, task coordinates."""
    z = np.zeros(model.n)
    kin = model.kinematics(q, z)
    J = kin.J_ee
    M_inv = model.inertia_inverse(q)
    M_x = np.linalg.inv(J @ M_inv @ J.T)
    J_pinv = M_inv @ J.T @ M_x  # dynamically consistent inverse (= J^-1 when square)
    Y_g, _ = model.regressor_affine(q, z, z, z)
    B = J_pinv.T @ Y_g
    K_I = g.k_a * (B @ np.linalg.solve(g.Gamma, B.T))
    return M_x, K_I, g.n[list(model.task_axes)]


def estimate_operating_points(g: LawGains, stiffness: StiffnessConfig
                              ) -> list[tuple[LawGains, float]]:
    """
    Return (gains, surface k) pairs over the k_s the stiffness estimate may command.

    The gains carry the k_s and lambda2 the law would use (module docstring); the list is empty
    when the estimate is off.
    """
    if not stiffness.enabled:
        return []
    lo, hi = min(stiffness.k_min, g.k_s), max(stiffness.k_max, g.k_s)
    over = 1.0 + 3.0 * stiffness.valid_tol
    points = []
    for k_s in np.geomspace(lo, hi, K_S_GRID):
        g_s = dataclasses.replace(g, k_s=float(k_s), lambda2=g.lambda2 * g.k_s / float(k_s))
        points += [(g_s, r * float(k_s)) for r in (over, 0.3, 0.1)]
    return points


def delay_margin(model: RobotModel, g: LawGains, q: np.ndarray, filter_hz: float = 0.0,
                 k_values: tuple[float, ...] | None = None,
                 stiffness: StiffnessConfig | None = None) -> float:
    """
    Return the worst delay margin (s) at configuration ``q``.

    The worst over the task inertia's extreme eigenvalues, both axes, and surface stiffnesses
    ``k_values`` (default k_max and fractions of it); with an enabled ``stiffness`` config also
    over the k_s the estimate may command (:func:`estimate_operating_points`).
    """
    M_x, K_I, n = _axis_gains(model, g, q)
    masses = np.linalg.eigvalsh(M_x)
    ks = k_values or (g.k_max, 0.3 * g.k_max, 0.1 * g.k_max)
    points = [(g, k) for k in ks]
    if stiffness is not None:
        points += estimate_operating_points(g, stiffness)
    worst = math.inf
    t_basis = np.linalg.svd(np.eye(len(n)) - np.outer(n, n))[0][:, :len(n) - 1]
    for m in (masses.min(), masses.max()):
        for t in t_basis.T:
            worst = min(worst, axis_margin(g, m, float(t @ K_I @ t)))
        for g_k, k in points:
            worst = min(worst, axis_margin(g_k, m, float(n @ K_I @ n), k, filter_hz))
    return worst
