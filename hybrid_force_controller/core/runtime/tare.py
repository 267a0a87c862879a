"""
Taring the force sensor: its bias, averaged while the tool is still and off the surface.

A real force/torque sensor reads a few newtons with nothing on it, and drifts; the
controller's f_d is 1 to 5 N. :class:`Tare` averages the raw reading ``F_raw`` (sensor frame,
before ``wrench_offset`` is subtracted) over ``duration`` seconds of sensor stamps, less what the
tool's weight explains (``F_S = R^T w_W`` out of contact: latest_inputs.py), so the bias is

    b = mean(F_raw) - R^T w_W.

The caller aborts it when the arm moves (any ``|qdot| >`` :data:`STILL_QDOT`) or the tool
touches, and refuses to start it in contact (runtime and node). Pure numpy; times are
arguments (the sensor's stamps).
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['STILL_QDOT', 'still', 'Tare']

STILL_QDOT = 0.01  # rad/s: a joint faster than this is moving (a still arm reads ~1e-3)


def still(qdot: np.ndarray) -> bool:
    """Say whether no joint moves faster than :data:`STILL_QDOT`."""
    return float(np.abs(qdot).max(initial=0.0)) <= STILL_QDOT


class Tare:
    """One tare: ``state`` is 'running', then 'done' (``offset``) or 'aborted' (``reason``)."""

    def __init__(self, duration: float, weight_S: np.ndarray | None = None) -> None:
        if not (duration > 0.0 and math.isfinite(duration)):
            raise ValueError(f'tare duration must be finite and > 0, got {duration}')
        self.duration = duration
        self.weight_S = np.zeros(3) if weight_S is None else np.asarray(weight_S, float)
        self.state, self.reason = 'running', ''
        self.offset: np.ndarray | None = None
        self.samples, self.t_first, self.t_last = 0, math.nan, math.nan
        self._sum = [0.0, 0.0, 0.0]

    @property
    def running(self) -> bool:
        return self.state == 'running'

    def add(self, fx: float, fy: float, fz: float, t: float) -> None:
        """Take one raw reading (sensor frame, N) stamped ``t``; finish after ``duration``."""
        if self.state != 'running':
            return
        if self.samples == 0:
            self.t_first = t
        s = self._sum
        s[0] += fx
        s[1] += fy
        s[2] += fz
        self.samples += 1
        self.t_last = t
        if t - self.t_first >= self.duration:
            self.offset = np.array(s) / self.samples - self.weight_S
            self.state = 'done'

    def abort(self, reason: str) -> None:
        """Stop without a result, saying why (the arm moved, the tool touched...)."""
        if self.state == 'running':
            self.state, self.reason = 'aborted', reason
