"""Signal conditioning for the force/torque path (pure numpy)."""
from __future__ import annotations

import math

import numpy as np

__all__ = ['LowPassFilter']


class LowPassFilter:
    """
    First-order low-pass filter in the manner of control_toolbox's LowPassFilter.

    ``y_k = y_{k-1} + a (u_k - y_{k-1})`` with ``a = 1 - exp(-2 pi f_c dt)``. It starts
    from the first finite sample (no transient from zero) and skips non-finite samples,
    keeping the last output. ``cutoff_hz <= 0`` passes samples through unchanged.
    """

    def __init__(self, cutoff_hz: float, size: int = 3) -> None:
        self.cutoff_hz = float(cutoff_hz)
        self._y = np.zeros(size)
        self._ready = False
        self._dt = self._a = -1.0

    @property
    def ready(self) -> bool:
        """Return True once a finite sample has been seen."""
        return self._ready

    @property
    def value(self) -> np.ndarray:
        """Return the current output (zeros before the first finite sample)."""
        return self._y

    def reset(self) -> None:
        """Forget the state; the next finite sample restarts the filter."""
        self._ready = False
        self._y[:] = 0.0
        self._dt = self._a = -1.0

    def update(self, u: np.ndarray, dt: float) -> bool:
        """
        Filter one sample taken ``dt`` seconds after the previous one.

        Returns False (and keeps the state) when ``u`` holds NaN/Inf. The few components are
        filtered as floats (each numpy operation on them would cost more than all of them).
        """
        u_list = u.tolist()
        if not math.isfinite(sum(u_list)):
            return False
        if not self._ready or self.cutoff_hz <= 0.0:
            self._y[:] = u
            self._ready = True
            return True
        if dt != self._dt:
            self._dt = dt
            self._a = 1.0 - math.exp(-2.0 * math.pi * self.cutoff_hz * max(dt, 0.0))
        a = self._a
        self._y[:] = [y + a * (x - y) for x, y in zip(u_list, self._y.tolist())]
        return True
