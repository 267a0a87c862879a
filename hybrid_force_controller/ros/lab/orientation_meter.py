"""
The tool's orientation in a running loop, from the sim's topics (tests and the lab).

An :class:`OrientationMeter` subscribes ``sim/tool_axis``, ``sim/contact_normal`` and the torque
of ``sim/contact_wrench`` (the true moment about the tool's centre) and, over a window of stamps,
reports what ``report`` does from a bag (tools/orientation_analysis.py): the angle between the
tool axis and the true normal (less a set tilt), RMS and largest, and the RMS tilt moment.
"""
from __future__ import annotations

import math
import threading
from typing import Any

import numpy as np

__all__ = ['OrientationMeter']


def _t(stamp: Any) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


class OrientationMeter:
    """Collect the tool axis, the true normal and the true moment on ``node`` (any spun node)."""

    def __init__(self, node: Any) -> None:
        from geometry_msgs.msg import Vector3Stamped, WrenchStamped
        self.lock = threading.Lock()
        self.axis: dict[float, np.ndarray] = {}
        self.normal: dict[float, np.ndarray] = {}
        self.moment: dict[float, np.ndarray] = {}
        for topic, store in (('sim/tool_axis', self.axis), ('sim/contact_normal', self.normal)):
            node.create_subscription(
                Vector3Stamped, topic,
                lambda m, s=store: self._put(s, m.header.stamp, m.vector), 1000)
        node.create_subscription(
            WrenchStamped, 'sim/contact_wrench',
            lambda m: self._put(self.moment, m.header.stamp, m.wrench.torque), 1000)

    def _put(self, store: dict, stamp: Any, v: Any) -> None:
        with self.lock:
            store[_t(stamp)] = np.array([v.x, v.y, v.z])

    def figures(self, t0: float, t1: float, tilt_rad: float = 0.0) -> dict[str, float]:
        """Return the tilt error (deg, RMS and max) and the RMS tilt moment (N m) over [t0, t1]."""
        with self.lock:
            rows = [(self.axis[t], n, self.moment.get(t)) for t, n in self.normal.items()
                    if t0 <= t <= t1 and t in self.axis]
        out = {'rms_tool_tilt_error_deg': math.nan, 'max_tool_tilt_error_deg': math.nan,
               'rms_moment_n_m': math.nan, 'orientation_samples': len(rows)}
        if not rows:
            return out
        a = np.array([r[0] for r in rows])
        n = np.array([r[1] for r in rows])
        angle = np.degrees(np.arccos(np.clip(np.sum(a * n, axis=1), -1.0, 1.0)))
        error = np.abs(angle - math.degrees(tilt_rad))
        out['rms_tool_tilt_error_deg'] = float(np.sqrt(np.mean(error ** 2)))
        out['max_tool_tilt_error_deg'] = float(error.max())
        m = np.array([r[2] for r in rows if r[2] is not None])
        if len(m):
            n_m = np.array([r[1] for r in rows if r[2] is not None])
            m_t = m - np.sum(m * n_m, axis=1)[:, None] * n_m
            out['rms_moment_n_m'] = float(np.sqrt(np.mean(np.sum(m_t ** 2, axis=1))))
        return out
