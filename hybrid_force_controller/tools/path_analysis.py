"""
The path metrics and the surface plane's coordinates of a run (pure numpy).

:func:`path_metrics` gives ``rms_path_error_m`` and ``max_path_error_m``: the tool's distance
from the desired point in the tangent plane, ``|(I - n n^T)(x - x_d)|``, with n the
controller's (from ``~/wrench_desired``, :attr:`RunLog.n_W`), while a user's path was
``running`` (``~/path_status`` recorded) or else over ``t >= t_start``.
:func:`surface_basis` gives the plane's axes the report draws the path in.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .analysis import RunLog, surface_axis, tangential_error

__all__ = ['PATH_METRIC_KEYS', 'path_metrics', 'path_window', 'surface_basis']

PATH_METRIC_KEYS = ('rms_path_error_m', 'max_path_error_m', 'path_window')


def surface_basis(n_W: np.ndarray) -> np.ndarray:
    """
    Return two unit vectors (rows) spanning the surface plane, right-handed about ``-n_W``.

    The first is :func:`surface_axis`'s base axis projected on the plane; seen from the tool
    (looking along n into the surface) the second is 90 degrees counter-clockwise from it.
    """
    n = np.asarray(n_W, dtype=float)
    u = np.eye(3)[surface_axis(n)]
    u = u - (u @ n) * n
    u /= np.linalg.norm(u)
    return np.array((u, np.cross(u, n)))


def path_window(log: RunLog, t_start: float = 5.0) -> tuple[np.ndarray, str]:
    """
    Return the samples of the path metrics and what they are.

    While a user's path was ``running`` when the run recorded it and one ran, else
    ``t >= t_start`` (as the position metrics).
    """
    if log.path_running is not None and log.path_running.any():
        return log.path_running.copy(), 'path running'
    return log.t >= t_start, f't >= {t_start:g} s'


def path_metrics(log: RunLog, t_start: float = 5.0) -> dict[str, Any]:
    """
    Return the path error: the tool's distance from the desired point in the tangent plane.

    Keys :data:`PATH_METRIC_KEYS`: RMS and max of ``|(I - n n^T)(x - x_d)|`` [m] over
    :func:`path_window` (n from the desired wrench), and the window's description. NaN
    when the window is empty.
    """
    window, what = path_window(log, t_start)
    e = tangential_error(log)[window]
    if e.size == 0:
        return {'rms_path_error_m': math.nan, 'max_path_error_m': math.nan,
                'path_window': what}
    return {'rms_path_error_m': float(np.sqrt(np.mean(e ** 2))),
            'max_path_error_m': float(e.max()), 'path_window': what}
