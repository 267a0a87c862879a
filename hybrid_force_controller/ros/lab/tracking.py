"""
Tracking figures of a running loop, from its topics (for ``bench --ros``).

A :class:`TrackingMeter` subscribes the controller's ``~/x``, ``~/x_desired`` and
``~/theta_hat`` and the sim's ``sim/contact_wrench`` (the true force) and, over a window of
stamps, reports the RMS tangential position error, the RMS normal force error and the time
out of contact (the core contact predicate on the true force), like ``report`` does from a
bag, and the figures of a recovery from a freeze (tools/recovery_figures.py).
"""
from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np

from ...core.runtime.contact import in_contact
from ...tools.recovery_figures import recovery_figures, theta_steady

__all__ = ['TrackingMeter']


def _t(stamp: Any) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


class TrackingMeter:
    """Collect position, reference and true force samples on ``node`` (any spun node)."""

    def __init__(self, node: Any, n_W: np.ndarray, f_d: float) -> None:
        from geometry_msgs.msg import PointStamped, WrenchStamped
        from std_msgs.msg import Float64MultiArray
        self.n_W = np.asarray(n_W, dtype=float)
        self.f_d_steps = [(-math.inf, f_d)]  # (from stamp, f_d): a parameter storm changes it
        self.lock = threading.Lock()
        self.x: dict[float, np.ndarray] = {}
        self.x_d: dict[float, np.ndarray] = {}
        self.f: list[tuple[float, float]] = []
        self._t_touch = math.nan  # first_contact's stamp, once found
        self.theta: list[tuple[float, tuple[float, ...]]] = []  # (wall time of reception, row)
        node.create_subscription(PointStamped, 'hybrid_force_controller/x',
                                 lambda m: self._point(self.x, m), 1000)
        node.create_subscription(PointStamped, 'hybrid_force_controller/x_desired',
                                 lambda m: self._point(self.x_d, m), 1000)
        node.create_subscription(WrenchStamped, 'sim/contact_wrench', self._on_force, 1000)
        node.create_subscription(Float64MultiArray, 'hybrid_force_controller/theta_hat',
                                 self._on_theta, 1000)

    def _on_theta(self, msg: Any) -> None:
        with self.lock:
            self.theta.append((time.time(), tuple(msg.data)))

    def theta_steady(self) -> bool:
        """
        Say whether theta_hat is learned (tools/recovery_figures.py ``theta_steady``).

        Within 10 % over 3 s: on the paper's path theta_hat keeps swinging around the masses,
        2-7 % peak to peak over any 2 s; the learning from masses 50 % off moves it far more.
        """
        with self.lock:
            thetas = list(self.theta)
        return theta_steady(np.array([t for t, _ in thetas]), np.array([r for _, r in thetas]),
                            span_s=3.0, tol=0.10)

    def recovery(self, t_stop: float, t_release: float, f_d: float) -> dict[str, float]:
        """Return the figures of the recovery from a freeze (tools/recovery_figures.py)."""
        with self.lock:
            forces = np.array(self.f)
            thetas = list(self.theta)
        t_th = np.array([t for t, _ in thetas])
        th = np.array([row for _, row in thetas])
        return recovery_figures(forces[:, 0], forces[:, 1], t_stop, t_release, f_d, t_th, th)

    def _point(self, store: dict, msg: Any) -> None:
        p = msg.point
        with self.lock:
            store[_t(msg.header.stamp)] = np.array([p.x, p.y, p.z])

    def _on_force(self, msg: Any) -> None:
        f = msg.wrench.force
        with self.lock:
            self.f.append((_t(msg.header.stamp), float(self.n_W @ [f.x, f.y, f.z])))

    def set_f_d(self, t: float, f_d: float) -> None:
        """f_d is ``f_d`` from stamp ``t`` on."""
        with self.lock:
            self.f_d_steps.append((t, f_d))

    def _f_d(self, t: np.ndarray) -> np.ndarray:
        starts, values = zip(*self.f_d_steps)
        return np.asarray(values)[np.searchsorted(np.asarray(starts), t, side='right') - 1]

    def settle_time(self, t0: float, f_d: float, tol: float = 0.05) -> float:
        """Time after ``t0`` from which the force stays within ``tol`` of ``f_d``, s (NaN)."""
        with self.lock:
            forces = [(t, f) for t, f in self.f if t >= t0]
        if not forces:
            return math.nan
        t, f = np.array(forces).T
        outside = np.flatnonzero(np.abs(f - f_d) > tol)
        if len(outside) == 0:
            return 0.0
        return math.nan if outside[-1] == len(t) - 1 else float(t[outside[-1] + 1] - t0)

    def first_contact(self) -> float:
        """Stamp of the first true-force sample in contact (f_d 0, the core predicate), s (NaN)."""
        with self.lock:
            if math.isnan(self._t_touch):
                self._t_touch = next((t for t, f in self.f if in_contact(f)), math.nan)
            return self._t_touch

    @property
    def latest(self) -> float:
        """Stamp of the newest force sample, s (0 before any)."""
        with self.lock:
            return self.f[-1][0] if self.f else 0.0

    def figures(self, t0: float, t1: float) -> dict[str, float]:
        """RMS position (m) and force (N) errors and contact lost (s) over [t0, t1]."""
        with self.lock:
            pairs = [(x, self.x_d[t]) for t, x in self.x.items()
                     if t0 <= t <= t1 and t in self.x_d]
            forces = [(t, f) for t, f in self.f if t0 <= t <= t1]
        P_t = np.eye(3) - np.outer(self.n_W, self.n_W)
        e_x = [P_t @ (x - x_d) for x, x_d in pairs]
        out = {'rms_position_error_m': math.nan, 'rms_force_error_n': math.nan,
               'contact_lost_s': math.nan, 'samples': len(forces)}
        if e_x:
            out['rms_position_error_m'] = float(np.sqrt(np.mean(np.sum(np.square(e_x), 1))))
        if len(forces) > 1:
            t, f = np.array(forces).T
            out['rms_force_error_n'] = float(np.sqrt(np.mean((f - self._f_d(t)) ** 2)))
            lost = np.array([not in_contact(v) for v in f[:-1]])
            out['contact_lost_s'] = float(np.sum(np.diff(t)[lost]))
            out['max_force_n'] = float(f.max())
        return out
