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

import numpy as np

from .stiffness import StiffnessConfig
from ..config.params import LawGains
from ..model.robot_model import RobotModel

__all__ = ['K_S_GRID', 'MarginCache', 'axis_loop', 'axis_margin', 'delay_margin',
           'estimate_operating_points', 'margins']

_W = np.logspace(-1.0, 4.5, 800)  # rad/s (the crossings found agree with 2000 points)
_S_GRID = 1j * _W
_BISECTIONS = 32  # |G| = 1 refined to 2^-32 of a grid step (log-spaced)
K_S_GRID = 5  # k_s values of the estimate's range in the margin (module docstring)


def _polyval(coeffs: np.ndarray, powers: np.ndarray) -> np.ndarray:
    """
    Evaluate row-wise polynomials at points given by their powers.

    ``coeffs`` (B, L), highest first; ``powers`` (L, W) for points shared by all rows, or
    (B, L) for one point a row (``s^(L-1) ... s^0``).
    """
    if powers.ndim == 2 and powers.shape[0] == coeffs.shape[1]:
        return coeffs @ powers.real + 1j * (coeffs @ powers.imag)
    return np.einsum('ij,ij->i', coeffs, powers)


def _powers(s: np.ndarray, L: int) -> np.ndarray:
    """Return ``s^(L-1), ..., s^0`` stacked along a new last axis."""
    return s[..., None] ** np.arange(L - 1, -1, -1)


def _stable_rows(char: np.ndarray) -> np.ndarray:
    """
    Return whether all roots of each characteristic polynomial lie in the open left half.

    Rows are coefficients, highest first, with leading zeros; rows of one degree share one
    batched eigenvalue problem of their companion matrices.
    """
    stable = np.zeros(len(char), dtype=bool)
    lead = np.argmax(char != 0.0, axis=1)
    for first in np.unique(lead):
        rows = np.flatnonzero(lead == first)
        c = char[rows, first:]
        deg = c.shape[1] - 1
        if deg == 0:
            stable[rows] = True
            continue
        comp = np.zeros((len(rows), deg, deg))
        comp[:, 0, :] = -c[:, 1:] / c[:, :1]
        comp[:, np.arange(1, deg), np.arange(deg - 1)] = 1.0
        stable[rows] = np.all(np.linalg.eigvals(comp).real < 0.0, axis=1)
    return stable


def margins(num: np.ndarray, den: np.ndarray) -> np.ndarray:
    """
    Return the delay margin (s) of each loop ``1 + e^{-s tau} num(s) / den(s)``, batched.

    ``num`` and ``den`` are (B, L) coefficient arrays (highest first, zero-padded on the
    left). A loop unstable without delay has margin 0; one whose ``|G|`` never crosses 1 on
    the grid has an infinite margin. Otherwise the margin is
    ``min (pi + arg G(j w) mod 2 pi) / w`` over the crossings ``|G(j w)| = 1``, each found
    on the log-spaced grid and refined by bisection, all crossings at once.
    """
    out = np.full(len(num), math.inf)
    grid = _powers(_S_GRID, num.shape[1]).T
    mag = np.abs(_polyval(num, grid) / _polyval(den, grid)) - 1.0
    rows, cols = np.nonzero(np.sign(mag[:, :-1]) != np.sign(mag[:, 1:]))
    if len(rows):
        lo, hi, sign_lo = _W[cols], _W[cols + 1], np.sign(mag[rows, cols])
        n_c, d_c = num[rows], den[rows]
        for _ in range(_BISECTIONS):
            mid = np.sqrt(lo * hi)
            s = _powers(1j * mid, num.shape[1])
            g = _polyval(n_c, s) / _polyval(d_c, s)
            above = (np.abs(g) - 1.0) * sign_lo > 0.0
            lo, hi = np.where(above, mid, lo), np.where(above, hi, mid)
        w = np.sqrt(lo * hi)
        s = _powers(1j * w, num.shape[1])
        g = _polyval(n_c, s) / _polyval(d_c, s)
        np.minimum.at(out, rows, ((math.pi + np.angle(g)) % (2.0 * math.pi)) / w)
    out[~_stable_rows(num + den)] = 0.0
    return out


def _cancel_s(num: np.ndarray, den: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cancel the factors ``s`` common to both polynomials (trailing zero coefficients)."""
    while len(num) > 1 and len(den) > 1 and num[-1] == 0.0 and den[-1] == 0.0:
        num, den = num[:-1], den[:-1]
    return num, den


def axis_loop(g: LawGains, m: float, K_I: float, k: float | None = None,
              filter_hz: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the open loop ``G = num / den`` of one task axis of mass ``m`` (kg).

    Along the surface when ``k`` is None, else along n against a surface of stiffness ``k``
    (N/m); the factors ``s`` common to both are cancelled.
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
        num = np.convolve([B, K_I, 0.0, 0.0], F)
        num[-3:] += (a, kd * l2 * k + K_I * c * l1 * k, K_I * l2 * k)
        den = np.convolve([m, 0.0, k, 0.0, 0.0], F)
    return _cancel_s(np.asarray(num, dtype=float), np.asarray(den, dtype=float))


def _stack(loops: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Stack (num, den) pairs into two left-zero-padded (B, L) arrays."""
    L = max(max(len(n), len(d)) for n, d in loops)
    num, den = np.zeros((len(loops), L)), np.zeros((len(loops), L))
    for i, (n, d) in enumerate(loops):
        num[i, L - len(n):], den[i, L - len(d):] = n, d
    return num, den


def axis_margin(g: LawGains, m: float, K_I: float, k: float | None = None,
                filter_hz: float = 0.0) -> float:
    """
    Delay margin (s) of one task axis of mass ``m`` (kg).

    Along the surface when ``k`` is None, else along n against a surface of stiffness ``k`` (N/m).
    """
    return float(margins(*_stack([axis_loop(g, m, K_I, k, filter_hz)]))[0])


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


def _pose_loops(model: RobotModel, g: LawGains, q: np.ndarray, filter_hz: float,
                points: list[tuple[LawGains, float]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Every axis loop of one pose: both extreme masses, tangent axes and normal points."""
    M_x, K_I, n = _axis_gains(model, g, q)
    masses = np.linalg.eigvalsh(M_x)
    t_basis = np.linalg.svd(np.eye(len(n)) - np.outer(n, n))[0][:, :len(n) - 1]
    loops = []
    for m in (masses.min(), masses.max()):
        loops += [axis_loop(g, m, float(t @ K_I @ t)) for t in t_basis.T]
        loops += [axis_loop(g_k, m, float(n @ K_I @ n), k, filter_hz) for g_k, k in points]
    return loops


def delay_margin(model: RobotModel, g: LawGains, q: np.ndarray, filter_hz: float = 0.0,
                 k_values: tuple[float, ...] | None = None,
                 stiffness: StiffnessConfig | None = None) -> float:
    """
    Return the worst delay margin (s) at configuration ``q``, or over the rows of a 2-D ``q``.

    The worst over the task inertia's extreme eigenvalues, both axes, and surface stiffnesses
    ``k_values`` (default k_max and fractions of it); with an enabled ``stiffness`` config also
    over the k_s the estimate may command (:func:`estimate_operating_points`). All the axis
    loops of all the poses are evaluated in one batch (:func:`margins`).
    """
    ks = k_values or (g.k_max, 0.3 * g.k_max, 0.1 * g.k_max)
    points = [(g, k) for k in ks]
    if stiffness is not None:
        points += estimate_operating_points(g, stiffness)
    loops = []
    for q_i in np.atleast_2d(np.asarray(q, dtype=float)):
        loops += _pose_loops(model, g, q_i, filter_hz, points)
    return float(margins(*_stack(loops)).min())


class MarginCache:
    """
    :func:`delay_margin` remembered by the values it depends on (the last ``size`` of them).

    The key holds the gains of the margin (lambda1, lambda2, Gamma, n, k_d, k_s, k_a, k_max),
    the filter cut-off, the stiffness estimate's range, and the pose: a set of f_d, or of
    values seen before, costs a dictionary look-up.
    """

    def __init__(self, size: int = 64) -> None:
        self.size = size
        self._values: dict[tuple, float] = {}

    @staticmethod
    def key(g: LawGains, q: np.ndarray, filter_hz: float,
            stiffness: StiffnessConfig | None) -> tuple:
        """Return the values the margin depends on, hashable."""
        gains = (g.lambda1, g.lambda2, g.Gamma.tobytes(), g.n.tobytes(), g.k_d, g.k_s,
                 g.k_a, g.k_max)
        k_range = None if stiffness is None or not stiffness.enabled else (
            stiffness.k_min, stiffness.k_max, stiffness.valid_tol)
        return gains, np.asarray(q, dtype=float).tobytes(), float(filter_hz), k_range

    def get(self, model: RobotModel, g: LawGains, q: np.ndarray, filter_hz: float = 0.0,
            stiffness: StiffnessConfig | None = None) -> float:
        """Return :func:`delay_margin` for these values, computed once."""
        key = self.key(g, q, filter_hz, stiffness)
        if key not in self._values:
            if len(self._values) >= self.size:
                self._values.pop(next(iter(self._values)))
            self._values[key] = delay_margin(model, g, q, filter_hz, stiffness=stiffness)
        return self._values[key]
