"""
An untimed polyline, timed at a speed with bounded acceleration (pure numpy, the node's thread).

:func:`time_polyline` turns the poses of a path that carries no stamps into positions sampled
every ``h`` seconds, at rest at both ends:

1. **Corners rounded within a tolerance.** Each corner of turn angle theta gets a circular
   fillet of radius ``R = tol / (1/cos(theta/2) - 1)`` (the arc passes ``tol`` from the
   vertex), tangent to both segments at ``d = R tan(theta/2)`` from the vertex; ``d`` is at
   most half of either segment (then R shrinks). With ``tol = 0``, or a reversal (theta
   close to pi), the tool stops at the vertex instead. The curve is then C1 in space.
2. **A curvature-limited speed profile.** On a grid in arclength (cells never straddle a
   line/arc boundary, so the curvature kappa of a cell is constant) the speed is capped by
   ``speed`` and, on an arc, by ``v^2 kappa <= eta a_max`` (``eta`` = :data:`LATERAL_SHARE`);
   it is 0 at both ends and at the stops. A forward and a backward pass limit the change of
   v^2 per cell to ``2 a_t ds`` with ``a_t = a_max`` on a line and ``a_max sqrt(1 - eta^2)``
   on an arc, so ``|p''|^2 = a_t^2 + (v^2 kappa)^2 <= a_max^2`` everywhere. v^2 is linear in
   s over a cell (a constant tangential acceleration), which gives each cell's time exactly.
3. **Sampled at h** by inverting s(t) in each cell.

The passes are min-plus scans (``w_i = min_j (cap_j + B_i - B_j)``), so they are vectorised.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['LATERAL_SHARE', 'Primitives', 'time_polyline']

LATERAL_SHARE = 0.8  # eta: the share of a_max an arc's centripetal acceleration may take
REVERSAL_RAD = math.pi - 1e-3  # a turn this sharp stops at the vertex (no fillet)
CELL_M = 5e-4  # arclength grid of the speed profile, m (coarser for very long paths)
MAX_CELLS = 200_000
_EPS = 1e-12


class Primitives:
    """
    Lines and arcs, one after the other (arclength ``s``); :meth:`at` evaluates them.

    A line is ``a + u ds``; an arc of radius R ``a + R (cos(ds/R) u + sin(ds/R) v)`` with ``a``
    its centre. ``stops`` are the arclengths where the tool must be at rest.
    """

    def __init__(self) -> None:
        self.s0: list[float] = []
        self.length: list[float] = []
        self.radius: list[float] = []  # 0: a line
        self.abc: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self.stops: list[float] = []
        self.total = 0.0

    def _add(self, length: float, radius: float, a: np.ndarray, u: np.ndarray,
             v: np.ndarray) -> None:
        if length <= _EPS:
            return
        self.s0.append(self.total)
        self.length.append(length)
        self.radius.append(radius)
        self.abc.append((a, u, v))
        self.total += length

    def line(self, p: np.ndarray, q: np.ndarray) -> None:
        """Append the segment from ``p`` to ``q``."""
        d = q - p
        length = float(np.linalg.norm(d))
        if length > _EPS:
            self._add(length, 0.0, p, d / length, np.zeros(3))

    def arc(self, t1: np.ndarray, d_in: np.ndarray, m: np.ndarray, radius: float,
            theta: float) -> None:
        """Append a fillet from ``t1`` (heading ``d_in``, turning toward ``m``) by ``theta``."""
        centre = t1 + radius * m
        self._add(radius * theta, radius, centre, -m, d_in)

    def at(self, s: np.ndarray) -> np.ndarray:
        """Return the points at arclengths ``s`` (clipped to the curve), shape (len(s), 3)."""
        s = np.clip(np.asarray(s, dtype=float), 0.0, self.total)
        j = np.clip(np.searchsorted(self.s0, s, side='right') - 1, 0, len(self.s0) - 1)
        ds = np.minimum(s - np.asarray(self.s0)[j], np.asarray(self.length)[j])
        a, u, v = (np.array([abc[k] for abc in self.abc])[j] for k in range(3))
        r = np.asarray(self.radius)[j]
        arc = r > 0.0
        phi = np.where(arc, ds / np.where(arc, r, 1.0), 0.0)
        along = np.where(arc, r * np.cos(phi), ds)[:, None] * u
        side = np.where(arc, r * np.sin(phi), 0.0)[:, None] * v
        return a + along + side


def _unit(d: np.ndarray) -> np.ndarray:
    return d / float(np.linalg.norm(d))


def _corners(pts: np.ndarray, tol: float) -> list[tuple[float, float, np.ndarray]]:
    """Return, per vertex, the trim d (0: none), the turn theta and the inward normal m."""
    out = [(0.0, 0.0, np.zeros(3))]
    for i in range(1, len(pts) - 1):
        a, b = pts[i] - pts[i - 1], pts[i + 1] - pts[i]
        d_in, d_out = _unit(a), _unit(b)
        theta = math.acos(min(1.0, max(-1.0, float(d_in @ d_out))))
        if theta < 1e-9 or tol <= 0.0 or theta > REVERSAL_RAD:
            out.append((0.0, theta, np.zeros(3)))
            continue
        radius = tol / (1.0 / math.cos(theta / 2) - 1.0)
        d = min(radius * math.tan(theta / 2), 0.5 * float(np.linalg.norm(a)),
                0.5 * float(np.linalg.norm(b)))
        out.append((d, theta, _unit(d_out - (d_out @ d_in) * d_in)))
    out.append((0.0, 0.0, np.zeros(3)))
    return out


def build_primitives(pts: np.ndarray, tol: float) -> Primitives:
    """Return the rounded curve through the distinct points ``pts`` (module docstring, 1)."""
    prims, corners = Primitives(), _corners(pts, tol)
    for i in range(len(pts) - 1):
        d_dir = _unit(pts[i + 1] - pts[i])
        start = pts[i] + corners[i][0] * d_dir
        end = pts[i + 1] - corners[i + 1][0] * d_dir
        prims.line(start, end)
        d, theta, m = corners[i + 1]
        if d > 0.0:
            prims.arc(end, d_dir, m, d / math.tan(theta / 2), theta)
        elif 0 < i + 1 < len(pts) - 1 and theta >= 1e-9:
            prims.stops.append(prims.total)  # a sharp corner: at rest there
    return prims


def _grid(prims: Primitives) -> tuple[np.ndarray, np.ndarray]:
    """Return the grid's nodes (arclength) and each cell's curvature."""
    step = max(CELL_M, prims.total / MAX_CELLS)
    nodes, kappa = [np.zeros(1)], []
    for s0, length, radius in zip(prims.s0, prims.length, prims.radius):
        cells = max(2, math.ceil(length / step))  # a middle node: v > 0 between stops
        nodes.append(s0 + length * np.arange(1, cells + 1) / cells)
        kappa.append(np.full(cells, 0.0 if radius == 0.0 else 1.0 / radius))
    return np.concatenate(nodes), np.concatenate(kappa)


def _min_plus(cap2: np.ndarray, gain: np.ndarray) -> np.ndarray:
    """Return ``w_i = min_{j <= i} (cap2_j + B_i - B_j)``, B the cumulative ``gain``."""
    B = np.concatenate(([0.0], np.cumsum(gain)))
    return B + np.minimum.accumulate(cap2 - B)


def speed_profile(prims: Primitives, speed: float, a_max: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return the grid's nodes s, v^2 at them and the times at them (module docstring, 2)."""
    s, kappa = _grid(prims)
    lateral = np.where(kappa > 0.0, LATERAL_SHARE * a_max / np.maximum(kappa, _EPS), np.inf)
    cap2 = np.full(s.size, speed * speed)
    cap2[:-1] = np.minimum(cap2[:-1], lateral)
    cap2[1:] = np.minimum(cap2[1:], lateral)
    cap2[[0, -1]] = 0.0
    cap2[np.searchsorted(s, prims.stops)] = 0.0  # stops are line/line boundaries: nodes
    a_t = np.where(kappa > 0.0, a_max * math.sqrt(1.0 - LATERAL_SHARE ** 2), a_max)
    gain = 2.0 * a_t * np.diff(s)
    w = _min_plus(cap2, gain)
    w = np.minimum(w, _min_plus(w[::-1], gain[::-1])[::-1])
    v = np.sqrt(np.maximum(w, 0.0))
    dt = 2.0 * np.diff(s) / np.maximum(v[:-1] + v[1:], _EPS)
    return s, w, np.concatenate(([0.0], np.cumsum(dt)))


def time_polyline(pts: np.ndarray, speed: float, a_max: float, tol: float,
                  h: float) -> np.ndarray:
    """
    Return the positions every ``h`` s along the distinct points ``pts``, at rest at both ends.

    The last sample is the last point (module docstring).
    """
    if len(pts) < 2:
        return np.array(pts, dtype=float).reshape(-1, 3)
    prims = build_primitives(pts, tol)
    s, w, t = speed_profile(prims, speed, a_max)
    tk = np.arange(math.ceil(t[-1] / h) + 1) * h
    j = np.clip(np.searchsorted(t, tk, side='right') - 1, 0, s.size - 2)
    tau = np.minimum(tk - t[j], t[j + 1] - t[j])  # past the end: at the end
    ds = np.diff(s)[j]
    accel = (w[j + 1] - w[j]) / (2.0 * ds)
    s_k = s[j] + np.sqrt(w[j]) * tau + 0.5 * accel * tau * tau
    s_k = np.clip(s_k, s[j], s[j + 1])
    return prims.at(s_k)
