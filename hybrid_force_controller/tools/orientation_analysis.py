"""
The tool's orientation in a run: how square the tool was to the part, the moments it felt.

Pure numpy on a :class:`~.analysis.RunLog` that recorded the sim tool's axis
(``/sim/tool_axis``) and the surface's true normal (``/sim/contact_normal``):

* ``rms_tool_tilt_error_deg`` and ``max_tool_tilt_error_deg``: the angle between the tool axis
  and the true normal at the contact, less the set tilt ``tilt_rad`` (``tool_tilt``; its
  magnitude: the axis ``tool_tilt`` from the normal scores 0), RMS and largest;
* ``rms_moment_n_m``: the true contact moment about the tool's centre across the normal (the
  tilt moments about the two tangent axes; ``/sim/contact_wrench``'s torque), RMS.

Over the same window as ``normal_error_deg`` (normal_analysis.py): in contact, from
:data:`~.normal_analysis.SETTLE_S` after sliding begins (the normal the tool follows is learnt
only while sliding). NaN without the topics or samples in the window.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .analysis import RunLog
from .normal_analysis import SETTLE_S, sliding_begins

__all__ = ['ORIENTATION_METRIC_KEYS', 'orientation_metrics', 'tool_tilt_deg']

ORIENTATION_METRIC_KEYS = ('rms_tool_tilt_error_deg', 'max_tool_tilt_error_deg',
                           'rms_moment_n_m')


def tool_tilt_deg(log: RunLog) -> np.ndarray:
    """Return the angle between the tool axis and the true normal at every sample, deg."""
    cos = np.sum(log.tool_axis_W * log.n_true_W, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def orientation_metrics(log: RunLog, tilt_rad: float = 0.0) -> dict[str, Any]:
    """Return :data:`ORIENTATION_METRIC_KEYS` (module docstring); NaN where unknown."""
    out = dict.fromkeys(ORIENTATION_METRIC_KEYS, math.nan)
    if log.n_true_W is None:
        return out
    t_slide = sliding_begins(log)
    window = (log.t >= t_slide + SETTLE_S) & log.in_contact
    if math.isnan(t_slide) or not window.any():
        return out
    if log.tool_axis_W is not None:
        error = np.abs(tool_tilt_deg(log)[window] - math.degrees(tilt_rad))
        out['rms_tool_tilt_error_deg'] = float(np.sqrt(np.mean(error ** 2)))
        out['max_tool_tilt_error_deg'] = float(error.max())
    if log.m_true_W is not None:
        m, n = log.m_true_W[window], log.n_true_W[window]
        m_t = m - np.sum(m * n, axis=1)[:, None] * n
        out['rms_moment_n_m'] = float(np.sqrt(np.mean(np.sum(m_t ** 2, axis=1))))
    return out
