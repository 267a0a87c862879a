"""
The learnt surface normal of a run against the truth (pure numpy; issue 24).

:func:`normal_metrics` gives ``normal_error_deg``: the largest angle between the controller's
normal (``~/surface_normal``, :attr:`RunLog.n_hat_W`) and the surface's true normal at the tool
(``/sim/contact_normal``, :attr:`RunLog.n_true_W`), in contact, from :data:`SETTLE_S` after
sliding begins. Sliding begins where the tool first moves along the surface (across the true
normal), in contact, faster than :data:`SLIDING_SPEED` (the estimate's default
``n_speed_floor``: below it the estimate holds) for :data:`SUSTAIN_S` on end (a contact's
settling at start-up is shorter), the speed from the recorded positions over
:data:`SPEED_WINDOW_S`. NaN (``null`` in metrics.json) when the run recorded no normal or
never slid.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .analysis import RunLog

__all__ = ['NORMAL_METRIC_KEYS', 'SETTLE_S', 'SLIDING_SPEED', 'normal_error_deg',
           'normal_metrics', 'sliding_begins']

NORMAL_METRIC_KEYS = ('normal_error_deg', 'sliding_begins_s')
SLIDING_SPEED = 0.01  # m/s
SPEED_WINDOW_S = 0.05
SETTLE_S = 2.0
SUSTAIN_S = 0.2


def normal_error_deg(log: RunLog) -> np.ndarray:
    """Return the angle between the controller's and the true normal at every sample, deg."""
    cos = np.sum(log.n_hat_W * log.n_true_W, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def sliding_begins(log: RunLog) -> float:
    """Return the time sliding begins (module docstring), s; NaN if the tool never slid."""
    t, x = log.t, log.x_W
    if t.size < 2:
        return math.nan
    dt = np.median(np.diff(t)) if np.any(np.diff(t) > 0.0) else 0.0
    k = max(1, int(round(SPEED_WINDOW_S / dt))) if dt > 0.0 else 1
    k = min(k, t.size - 1)
    span = np.maximum(t[k:] - t[:-k], 1e-12)
    v = (x[k:] - x[:-k]) / span[:, None]
    n = log.n_true_W[k:] if log.n_true_W is not None else log.n_W
    v_t = v - (np.sum(v * n, axis=1)[:, None] * n if n.ndim == 2 else np.outer(v @ n, n))
    moving = (np.linalg.norm(v_t, axis=1) >= SLIDING_SPEED) & log.in_contact[k:]
    edges = np.diff(np.concatenate(([0], moving.astype(np.int8), [0])))
    t_k = t[k:]
    for b, e in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)):
        if t_k[e - 1] - t_k[b] >= SUSTAIN_S:
            return float(t_k[b])
    return math.nan


def normal_metrics(log: RunLog) -> dict[str, Any]:
    """
    Return ``normal_error_deg`` and ``sliding_begins_s`` (:data:`NORMAL_METRIC_KEYS`).

    Both NaN without both normals recorded; the error NaN when the tool never slid or the
    window after :data:`SETTLE_S` holds no sample in contact.
    """
    if log.n_hat_W is None or log.n_true_W is None:
        return {'normal_error_deg': math.nan, 'sliding_begins_s': math.nan}
    t_slide = sliding_begins(log)
    window = (log.t >= t_slide + SETTLE_S) & log.in_contact
    if math.isnan(t_slide) or not window.any():
        return {'normal_error_deg': math.nan, 'sliding_begins_s': t_slide}
    return {'normal_error_deg': float(normal_error_deg(log)[window].max()),
            'sliding_begins_s': t_slide}
