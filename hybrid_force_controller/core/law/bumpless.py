"""
Bumpless restart: the effort blends from the one the hardware held (pure numpy).

A deactivated controller stops commanding and the hardware holds its last effort (a
JointGroupEffortController keeps its last command); meanwhile the arm moves under that
held effort, so on re-activation the law's first effort differs from it (1.5 N m after
1 s inactive on the paper's arm). :class:`RestartBlend` fades from the held effort to the
law's with a cosine over ``BUMPLESS_S``, so the command is continuous at re-activation.
Times are arguments.
"""
from __future__ import annotations

import math

import numpy as np

__all__ = ['BUMPLESS_S', 'RestartBlend', 'cosine_fade']

BUMPLESS_S = 0.1  # the blend's length, s


def cosine_fade(s: float) -> float:
    """Return the weight ``(1 + cos(pi s)) / 2`` of a fade: 1 for ``s <= 0``, 0 for ``s >= 1``."""
    return 0.0 if s >= 1.0 else 0.5 * (1.0 + math.cos(math.pi * max(s, 0.0)))


class RestartBlend:
    """Blend efforts after a restart from the held one (module docstring)."""

    def __init__(self) -> None:
        self._held: np.ndarray | None = None
        self._t0 = math.nan

    def arm(self, tau_held: np.ndarray | None) -> None:
        """Blend from ``tau_held`` from the next effort on (None: nothing was held)."""
        self._held = None if tau_held is None else np.array(tau_held, dtype=float)
        self._t0 = math.nan

    def __call__(self, tau: np.ndarray, t: float) -> np.ndarray:
        """Return ``w tau_held + (1 - w) tau`` at time ``t``, ``w`` from 1 to 0 (cosine)."""
        if self._held is None:
            return tau
        if math.isnan(self._t0):
            self._t0 = t
        w = cosine_fade((t - self._t0) / BUMPLESS_S)
        if w == 0.0:
            self._held = None
            return tau
        return w * self._held + (1.0 - w) * tau
