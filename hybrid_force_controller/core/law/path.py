"""
A user's path along the surface (``~/path``): its checks, its plan, its evaluation (pure numpy).

:func:`plan_path` runs on the node's thread when a path arrives; the control thread only
evaluates the result, :meth:`PathPlan.rows` (an index and four weights per tick).

* **Tangential only.** The poses are projected onto the subspace the tool follows: the
  surface's tangent plane ``I - n n^T`` within the arm's task space (the law, eq. (11), uses
  only that part of x_d; along n the force loop acts). Speeds are checked on that part.
* **Timed** (the stamps are not all equal): pose i is reached ``stamp_i - stamp_0`` seconds
  after the first, linearly in between; a segment faster than ``max_speed`` is refused.
* **Untimed** (all stamps equal, e.g. zero): corners rounded within ``corner_tolerance`` and
  timed at ``speed`` with ``|a| <= max_accel`` (path_geometry.py), at rest at both ends.
* **Transit.** The plan starts where the current reference would stop: ``x + v T / 2``, T
  = :func:`stop_time` (the runtime blends into it with that monotone stop, motion.py). When
  the first pose is more than :data:`MIN_TRANSIT_M` from there, an untimed straight transit
  to it comes first: the spline is at rest at the first pose at ``transit_s + h``.
* **The spline.** The samples ``c_k`` (every ``h`` = :data:`SAMPLE_S`) are the control points
  of a uniform cubic B-spline whose end points are repeated twice more: x_d, xdot_d and
  xddot_d are continuous everywhere, and the spline starts and ends at rest with zero
  acceleration. Its velocity is a convex combination of the first differences of the
  samples, its acceleration of their second differences (each an average of the sampled
  curve's p''), so neither exceeds the sampled curve's bound: ``|xddot_d| <= max_accel``
  for an untimed path. It trails the samples by one step h: pose i of a timed path is
  reached at ``stamp_i + h``, and the plan lasts the samples' time ``+ 2 h``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .path_geometry import time_polyline

__all__ = ['MAX_DURATION_S', 'PathError', 'PathLimits', 'PathPlan', 'SAMPLE_S', 'check_path',
           'follow_basis', 'plan_path', 'stop_time']

SAMPLE_S = 0.01  # h: the spline's knot spacing, s
MAX_DURATION_S = 10000.0  # a longer plan is refused (1e6 samples, 24 MB)
MIN_TRANSIT_M = 1e-4  # a start closer than this to the first pose is left to the blend
_SAME_M = 1e-9  # consecutive poses closer than this are one
BLEND_MIN_S = 0.05  # the shortest blend into a path or a stop, s


class PathError(ValueError):
    """A path is refused; the message says why."""


@dataclass(frozen=True)
class PathLimits:
    """The ``path_*`` parameters: m/s, m/s^2, m/s, poses, m."""

    speed: float
    max_accel: float
    max_speed: float
    max_poses: int
    corner_tolerance: float


def stop_time(speed: float, a_max: float) -> float:
    """
    Return T of the monotone stop from ``speed`` (m/s) at most ``a_max`` (m/s^2), s.

    Blending (reference.py) from (x, v) into a point held at ``x + v T / 2`` over T gives the
    velocity ``v (1 - s)^2 (1 + 2 s)``, s = t / T: it never reverses, and its deceleration is at
    most ``1.5 |v| / T``.
    """
    return max(BLEND_MIN_S, 1.5 * speed / a_max)


def follow_basis(n_W: np.ndarray, task_axes: Sequence[int]) -> np.ndarray:
    """Return an orthonormal basis (3, k) of the tangent plane of ``n_W`` in the task space."""
    E = np.eye(3)[:, list(task_axes)]
    n = np.asarray(n_W, dtype=float)
    T = E - np.outer(n, n @ E)
    U, sv, _ = np.linalg.svd(T, full_matrices=False)
    return U[:, sv > 1e-9]


def check_path(points_W: np.ndarray, stamps: np.ndarray, limits: PathLimits,
               others: np.ndarray | None = None) -> None:
    """
    Refuse a path with too many poses, a non-finite value or stamps going back.

    ``points_W`` (N, 3), ``stamps`` (N,) s, ``others`` (N, ...) further numbers that must be
    finite (the orientations). Raises :class:`PathError` with the reason.
    """
    count = len(points_W)
    if count > limits.max_poses:
        raise PathError(f'{count} poses: more than path_max_poses = {limits.max_poses}')
    for name, arr in (('position', points_W), ('stamp', stamps), ('orientation', others)):
        if arr is None or not len(arr):
            continue
        bad = ~np.isfinite(np.asarray(arr, dtype=float).reshape(len(arr), -1)).all(axis=1)
        if bad.any():
            raise PathError(f'non-finite {name} in pose {int(np.argmax(bad))}')
    back = np.flatnonzero(np.diff(stamps) < 0.0)
    if back.size:
        i = int(back[0])
        raise PathError(f'non-monotonic stamps: pose {i + 1} at {stamps[i + 1]:.6g} s comes '
                        f'before pose {i} at {stamps[i]:.6g} s')


def _check_speed(pts: np.ndarray, t: np.ndarray, max_speed: float) -> None:
    """Refuse a timed path with a segment faster than ``max_speed`` (tangential part)."""
    dist = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    dt = np.diff(t)
    with np.errstate(divide='ignore', invalid='ignore'):
        v = np.where(dist > _SAME_M, dist / dt, 0.0)
    fast = np.flatnonzero(~(v <= max_speed))
    if fast.size:
        i = int(fast[0])
        raise PathError(f'faster than path_max_speed = {max_speed:g} m/s: {v[i]:.4g} m/s '
                        f'from pose {i} to pose {i + 1}')


def _distinct(pts: np.ndarray) -> np.ndarray:
    """Drop poses that repeat the one before."""
    keep = np.concatenate(([True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > _SAME_M))
    return pts[keep]


def _timed_samples(pts: np.ndarray, t: np.ndarray, limits: PathLimits) -> np.ndarray:
    _check_speed(pts, t, limits.max_speed)
    if t[-1] > MAX_DURATION_S:
        raise PathError(f'longer than {MAX_DURATION_S:g} s: {t[-1]:.6g} s')
    tk = np.minimum(np.arange(int(np.ceil(t[-1] / SAMPLE_S)) + 1) * SAMPLE_S, t[-1])
    return np.column_stack([np.interp(tk, t, pts[:, k]) for k in range(3)])


def _untimed_samples(pts: np.ndarray, limits: PathLimits) -> np.ndarray:
    pts = _distinct(pts)
    length = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum())
    if length / limits.speed > MAX_DURATION_S:  # at least this long
        raise PathError(f'longer than {MAX_DURATION_S:g} s at path_speed = {limits.speed:g} '
                        f'm/s: {length:.6g} m')
    return time_polyline(pts, limits.speed, limits.max_accel, limits.corner_tolerance,
                         SAMPLE_S)


def plan_path(points_W: np.ndarray, stamps: np.ndarray, start_W: np.ndarray | None,
              n_W: np.ndarray, task_axes: Sequence[int], limits: PathLimits,
              start_v_W: np.ndarray | None = None) -> PathPlan:
    """
    Check and plan a path of ``points_W`` (N >= 1, base frame) stamped ``stamps`` (s).

    ``start_W``, ``start_v_W``: where the reference is and how fast it moves (None: at the
    first pose, at rest). Raises :class:`PathError` with the reason (module docstring).
    """
    points_W, stamps = np.asarray(points_W, dtype=float), np.asarray(stamps, dtype=float)
    check_path(points_W, stamps, limits)
    if not len(points_W):
        raise PathError('an empty path has no plan (it stops the motion)')
    B = follow_basis(n_W, task_axes)
    P = B @ B.T
    o = points_W[0] if start_W is None else np.asarray(start_W, dtype=float)
    if start_v_W is not None:  # where it would stop
        v = P @ np.asarray(start_v_W, dtype=float)
        o = o + 0.5 * stop_time(float(np.linalg.norm(v)), limits.max_accel) * v
    pts = o + (points_W - o) @ P
    t = stamps - stamps[0]
    timed = bool(np.any(t != 0.0))
    samples = _timed_samples(pts, t, limits) if timed else _untimed_samples(pts, limits)
    transit_s = 0.0
    if np.linalg.norm(pts[0] - o) > MIN_TRANSIT_M:
        lead = time_polyline(np.array((o, pts[0])), limits.speed, limits.max_accel, 0.0,
                             SAMPLE_S)
        transit_s = len(lead) * SAMPLE_S  # three samples at the first pose: at rest there
        samples = np.concatenate((lead, samples[:1], samples))
    if (len(samples) + 1) * SAMPLE_S > MAX_DURATION_S:
        raise PathError(f'longer than {MAX_DURATION_S:g} s with the transit')
    return PathPlan(samples, SAMPLE_S, timed, transit_s)


class PathPlan:
    """
    The planned path as a uniform cubic B-spline (module docstring); O(1) per evaluation.

    ``duration`` (s) is the spline's; ``v_peak`` its largest speed (m/s); ``transit_s`` the
    transit's part of it; ``end_W`` where it rests at the end.
    """

    def __init__(self, samples_W: np.ndarray, h: float, timed: bool = False,
                 transit_s: float = 0.0) -> None:
        c = np.asarray(samples_W, dtype=float).reshape(-1, 3)
        self.Q = np.concatenate((c[:1], c[:1], c, c[-1:], c[-1:]))
        self.h, self.timed, self.transit_s = h, timed, transit_s
        self.segments = len(c) + 1
        self.duration = self.segments * h
        self.end_W = c[-1].copy()
        steps = np.linalg.norm(np.diff(c, axis=0), axis=1) if len(c) > 1 else np.zeros(1)
        self.v_peak = float(steps.max()) / h

    def rows(self, sigma: float, sdot: float = 1.0, sddot: float = 0.0) -> np.ndarray:
        """
        Return x_d, xdot_d, xddot_d at the plan's time ``sigma`` (s) as a new (3, 3) array.

        With a time scaling (path_run.py) ``sigma`` moves at ``sdot`` (and ``sddot``): the
        rows are ``p``, ``p' sdot`` and ``p'' sdot^2 + p' sddot``, folded into the weights.
        """
        u = float(sigma) / self.h
        if u >= self.segments:
            rows = np.zeros((3, 3))
            rows[0] = self.end_W
            return rows
        i = int(u) if u > 0.0 else 0
        f = u - i if u > 0.0 else 0.0
        g, f2, h = 1.0 - f, f * f, self.h
        f3, h2 = f2 * f, h * h
        v = (-0.5 * g * g / h, (1.5 * f2 - 2.0 * f) / h, (-1.5 * f2 + f + 0.5) / h, 0.5 * f2 / h)
        a = (g / h2, (3.0 * f - 2.0) / h2, (1.0 - 3.0 * f) / h2, f / h2)
        if sdot != 1.0 or sddot != 0.0:
            s2 = sdot * sdot
            a = tuple(ak * s2 + vk * sddot for ak, vk in zip(a, v))
            v = tuple(vk * sdot for vk in v)
        W = np.array(((g * g * g / 6.0, (3.0 * f3 - 6.0 * f2 + 4.0) / 6.0,
                       (-3.0 * f3 + 3.0 * f2 + 3.0 * f + 1.0) / 6.0, f3 / 6.0), v, a))
        return W.dot(self.Q[i:i + 4])

    def polyline(self, max_points: int = 500) -> np.ndarray:
        """Return the path's points, at most ``max_points`` (the ends included), for drawing."""
        c = self.Q[2:-2]
        step = max(1, int(np.ceil(len(c) / max_points)))
        return np.concatenate((c[::step], c[-1:])) if (len(c) - 1) % step else c[::step]
