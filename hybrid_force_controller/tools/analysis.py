"""
Run logs and tracking metrics of the hybrid force/motion controller.

Pure numpy: a :class:`RunLog` holds every signal of one run on a common time base (the
stamps of the end-effector position topic) and :func:`compute_metrics` reduces it to the
numbers the report, the benchmarks and the tests compare (Figs. 3-5 of the paper as
scalars). Frames: ``_W`` is the robot base frame.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
from typing import Any

import numpy as np

__all__ = ['AnalysisError', 'METRIC_KEYS', 'RunLog', 'align', 'compute_metrics',
           'contact_lost_time', 'json_safe', 'normal_force_error', 'surface_axis',
           'tangential_error']

METRIC_KEYS = ('rms_position_error_m', 'max_position_error_m', 'rms_force_error_n',
               'max_force_error_n', 'contact_lost_s', 'contact_lost_window_s',
               'theta_hat_final', 'wall_time_s',
               'sim_time_s', 'stiffness_estimate_n_per_m')

_UNIT_TOL = 1e-6


class AnalysisError(ValueError):
    """A run log or a metric request is invalid; the message names the offending field."""


def _as_array(name: str, value: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    """
    Return ``value`` as a finite float array of ``shape`` (``None``: any length).

    Raises
    ------
    AnalysisError
        Wrong number of dimensions, wrong size or a non-finite entry.

    """
    try:
        arr = np.array(value, dtype=float)  # a private copy, frozen below
    except (TypeError, ValueError) as exc:
        raise AnalysisError(f'{name}: not numeric ({exc})') from None
    ok = arr.ndim == len(shape) and all(s is None or s == n for s, n in zip(shape, arr.shape))
    if not ok:
        want = '(' + ', '.join('N' if s is None else str(s) for s in shape) + ')'
        raise AnalysisError(f'{name}: expected shape {want}, got {arr.shape}')
    if not np.all(np.isfinite(arr)):
        raise AnalysisError(f'{name}: contains NaN or inf')
    arr.flags.writeable = False
    return arr


@dataclass(frozen=True)
class RunLog:
    """
    All signals of one run, sampled on the stamps of the position topic.

    Attributes
    ----------
    t : numpy.ndarray, shape (N,)
        Seconds from run start, non-decreasing.
    x_W, x_d_W : numpy.ndarray, shape (N, 3)
        Actual and desired end-effector position in the base frame [m].
    f_W, f_d_W : numpy.ndarray, shape (N, 3)
        Measured and desired force the tool exerts on the surface, base frame [N].
    n_W : numpy.ndarray, shape (3,)
        Unit surface normal pointing into the surface (the direction the tool pushes).
    theta_hat : numpy.ndarray, shape (N, p)
        Estimated dynamic parameters.
    theta_names : tuple of str
        Names of the ``p`` parameters.
    in_contact : numpy.ndarray of bool, shape (N,)
        Whether the tool touches the surface.
    theta_true : numpy.ndarray, shape (p,), optional
        True parameters when known (simulation).
    f_true_W : numpy.ndarray, shape (N, 3), optional
        Noise-free contact force when known (simulation with a noisy sensor).
    k_hat : numpy.ndarray, shape (N,), optional
        The controller's online stiffness estimate [N/m]; NaN where it was unknown (not
        yet valid). None when the run did not record it.
    k_true : float, optional
        The surface's true stiffness [N/m] when known (simulation).
    path_running : numpy.ndarray of bool, shape (N,), optional
        Whether a user's path was being followed (``~/path_status`` ``running``); None when
        the run did not record it.
    n_hat_W : numpy.ndarray, shape (N, 3), optional
        The normal the controller used (``~/surface_normal``: n, or its estimate); None when
        not recorded. The tangential error is then taken in its tangent plane at each sample.
    n_true_W : numpy.ndarray, shape (N, 3), optional
        The surface's true normal at the tool (``/sim/contact_normal``); None when unknown.
        The normal force error is then the true force along it.
    tool_axis_W : numpy.ndarray, shape (N, 3), optional
        The sim tool's axis (``/sim/tool_axis``: the end effector's z, a disc's axis); None
        when not recorded.
    m_true_W : numpy.ndarray, shape (N, 3), optional
        The true moment the tool exerts on the part about the tool's centre (the torque of
        ``/sim/contact_wrench``), N m; None when not recorded.

    """

    t: np.ndarray
    x_W: np.ndarray
    x_d_W: np.ndarray
    f_W: np.ndarray
    f_d_W: np.ndarray
    n_W: np.ndarray
    theta_hat: np.ndarray
    theta_names: tuple[str, ...]
    in_contact: np.ndarray
    theta_true: np.ndarray | None = None
    f_true_W: np.ndarray | None = None
    k_hat: np.ndarray | None = None
    k_true: float | None = None
    path_running: np.ndarray | None = None
    n_hat_W: np.ndarray | None = None
    n_true_W: np.ndarray | None = None
    tool_axis_W: np.ndarray | None = None
    m_true_W: np.ndarray | None = None

    @classmethod
    def from_result(cls, result: Any) -> 'RunLog':
        """
        Build the log of an offline run.

        ``result`` is a :class:`~hybrid_force_controller.core.offline.scenario.ScenarioResult`.
        """
        return cls(t=result.t, x_W=result.x_W, x_d_W=result.x_d_W, f_W=result.f_W,
                   f_d_W=result.f_d_W, n_W=result.n_W, theta_hat=result.theta_hat,
                   theta_names=result.theta_names, in_contact=result.in_contact,
                   theta_true=result.theta_true, f_true_W=result.f_true_W,
                   k_hat=getattr(result, 'k_hat', None), k_true=getattr(result, 'k_true', None))

    def __post_init__(self) -> None:
        """Copy every field to a read-only float/bool array; validate shapes and values."""
        for name, value in _validated_fields(self).items():
            object.__setattr__(self, name, value)


def _validated_fields(log: RunLog) -> dict[str, Any]:
    """
    Check every field of ``log`` and return the coerced values by name.

    Raises
    ------
    AnalysisError
        On the first invalid field.

    """
    t = _as_array('t', log.t, (None,))
    n = t.shape[0]
    if n == 0:
        raise AnalysisError('t: run log has no samples')
    if np.any(np.diff(t) < 0.0):
        raise AnalysisError('t: time stamps must be non-decreasing')
    out: dict[str, Any] = {'t': t}
    for name in ('x_W', 'x_d_W', 'f_W', 'f_d_W'):
        out[name] = _as_array(name, getattr(log, name), (n, 3))
    n_W = _as_array('n_W', log.n_W, (3,))
    if abs(float(np.linalg.norm(n_W)) - 1.0) > _UNIT_TOL:
        raise AnalysisError(f'n_W: must be a unit vector, |n_W| = {np.linalg.norm(n_W):.6g}')
    out['n_W'] = n_W
    theta_hat = _as_array('theta_hat', log.theta_hat, (n, None))
    p = theta_hat.shape[1]
    names = tuple(log.theta_names)
    if len(names) != p or not all(isinstance(s, str) for s in names):
        raise AnalysisError(f'theta_names: expected {p} strings, got {names!r}')
    out.update(theta_hat=theta_hat, theta_names=names)
    out['in_contact'] = _flags('in_contact', log.in_contact, n)  # astype copies
    out['theta_true'] = None if log.theta_true is None else _as_array(
        'theta_true', log.theta_true, (p,))
    out['f_true_W'] = None if log.f_true_W is None else _as_array(
        'f_true_W', log.f_true_W, (n, 3))
    out['k_hat'] = None if log.k_hat is None else _estimate(log.k_hat, n)
    out['path_running'] = None if log.path_running is None else _flags(
        'path_running', log.path_running, n)
    for name in ('n_hat_W', 'n_true_W', 'tool_axis_W', 'm_true_W'):
        value = getattr(log, name)
        out[name] = None if value is None else _as_array(name, value, (n, 3))
    if log.k_true is not None:
        out['k_true'] = float(_as_array('k_true', log.k_true, ()))
        if not out['k_true'] > 0.0:
            raise AnalysisError(f'k_true: must be > 0, got {out["k_true"]}')
    return out


def _flags(name: str, value: Any, n: int) -> np.ndarray:
    """Return (N,) booleans (read-only) or raise :class:`AnalysisError`."""
    arr = np.asarray(value)
    if arr.shape != (n,) or arr.dtype.kind not in 'bui':
        raise AnalysisError(f'{name}: expected {n} booleans, got shape {arr.shape}')
    arr = arr.astype(bool)
    arr.flags.writeable = False
    return arr


def _estimate(value: Any, n: int) -> np.ndarray:
    """
    Check the stiffness estimate and return it as (N,) floats (read-only).

    NaN (unknown) is allowed; finite values must be > 0.
    """
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise AnalysisError(f'k_hat: not numeric ({exc})') from None
    if arr.shape != (n,):
        raise AnalysisError(f'k_hat: expected shape ({n},), got {arr.shape}')
    known = arr[~np.isnan(arr)]
    if not np.all(np.isfinite(known) & (known > 0.0)):
        raise AnalysisError('k_hat: values must be NaN (unknown) or finite and > 0')
    arr.flags.writeable = False
    return arr


def align(t_query: np.ndarray, t_src: np.ndarray, y_src: np.ndarray) -> np.ndarray:
    """
    Resample ``y_src`` onto ``t_query`` by zero-order hold.

    Each query takes the latest source sample stamped at or before it; queries earlier
    than the first source sample take the first sample (the signal is held backwards).

    Parameters
    ----------
    t_query : numpy.ndarray, shape (M,)
        Query stamps (any unit, same as ``t_src``).
    t_src : numpy.ndarray, shape (K,)
        Non-decreasing source stamps, ``K >= 1``.
    y_src : numpy.ndarray, shape (K, ...)
        Source samples.

    Returns
    -------
    numpy.ndarray, shape (M, ...)
        ``y_src`` held at every query stamp.

    Raises
    ------
    AnalysisError
        Empty source, mismatched lengths or unsorted source stamps.

    """
    t_q = np.asarray(t_query, dtype=float)
    t_s = np.asarray(t_src, dtype=float)
    y_s = np.asarray(y_src)
    if t_s.ndim != 1 or t_s.size == 0 or y_s.shape[:1] != t_s.shape:
        raise AnalysisError(f'align: need K >= 1 source stamps matching y_src, got '
                            f'{t_s.shape} stamps and {y_s.shape} samples')
    if np.any(np.diff(t_s) < 0.0):
        raise AnalysisError('align: source stamps must be non-decreasing')
    idx = np.searchsorted(t_s, t_q, side='right') - 1
    return y_s[np.clip(idx, 0, t_s.size - 1)]


def tangential_error(log: RunLog) -> np.ndarray:
    """
    Norm of the position error projected on the surface, ``|(I - n n^T)(x - x_d)|``.

    n is the controller's normal at each sample when the run recorded it (``n_hat_W``), else
    ``n_W``. With a learnt normal the reference lies on its tangent plane, displaced along the
    told n from the path's point, so this is the error in the path's own plane over at most
    ``1 / cos`` of the angle between the two (4.7 % at 0.3 rad).

    Returns
    -------
    numpy.ndarray, shape (N,)
        Tangential position error [m] at every sample.

    """
    e_W = log.x_W - log.x_d_W
    if log.n_hat_W is not None:
        n = log.n_hat_W
        return np.linalg.norm(e_W - np.sum(e_W * n, axis=1)[:, None] * n, axis=1)
    n = log.n_W
    e_tan_W = e_W - np.outer(e_W @ n, n)
    return np.linalg.norm(e_tan_W, axis=1)


def normal_force_error(log: RunLog) -> np.ndarray:
    """
    Signed normal force error ``n^T (f - f_d)``; uses ``f_true_W`` when it is known.

    With the surface's true normal at each sample (``n_true_W``) it is the force along it less
    the desired force's magnitude: what the tool presses on the surface whatever the
    controller believes its normal to be.

    Returns
    -------
    numpy.ndarray, shape (N,)
        Normal force error [N] at every sample.

    """
    f_W = log.f_W if log.f_true_W is None else log.f_true_W
    if log.n_true_W is not None:
        return np.sum(f_W * log.n_true_W, axis=1) - np.linalg.norm(log.f_d_W, axis=1)
    return (f_W - log.f_d_W) @ log.n_W


def contact_lost_time(log: RunLog, t_start: float = -math.inf) -> float:
    """
    Total time out of contact after the first contact sample (and after ``t_start``).

    Sample ``i`` lasts ``t[i+1] - t[i]`` (zero-order hold); the last sample lasts zero.
    A run that never touches the surface counts its whole duration as lost.

    Returns
    -------
    float
        Seconds out of contact.

    """
    durations = np.diff(log.t, append=log.t[-1])
    touched = np.flatnonzero(log.in_contact)
    if touched.size == 0:
        return float(log.t[-1] - max(log.t[0], min(t_start, log.t[-1])))
    after = (np.arange(log.t.size) >= touched[0]) & (log.t >= t_start)
    return float(np.sum(durations[after & ~log.in_contact]))


def surface_axis(n_W: np.ndarray) -> int:
    """
    Index of the first base axis tangent to the surface (least aligned with ``n_W``).

    For the paper arm, ``n_W = (0, -1, 0)`` gives 0: the motion runs along base x.
    """
    a = np.abs(np.asarray(n_W, dtype=float))
    tangent = np.flatnonzero(a <= _UNIT_TOL)
    return int(tangent[0]) if tangent.size else int(np.argmin(a))


def compute_metrics(log: RunLog, t_start: float = 5.0,
                    wall_time_s: float = float('nan')) -> dict[str, Any]:
    """
    Tracking metrics of one run.

    Parameters
    ----------
    log : RunLog
        The run.
    t_start : float
        Position and force errors use samples with ``t >= t_start`` (skip the transient).
    wall_time_s : float
        Wall-clock duration of the run, passed through (NaN when unknown).

    Returns
    -------
    dict
        Keys :data:`METRIC_KEYS`: RMS/max tangential position error [m], RMS/max absolute
        normal force error [N], ``contact_lost_s`` over the whole run and
        ``contact_lost_window_s`` over ``t >= t_start`` (after the first contact), final
        ``theta_hat``
        as a list, ``wall_time_s``, ``sim_time_s = t[-1] - t[0]`` and
        ``stiffness_estimate_n_per_m``, the stiffness estimate at the last sample [N/m]:
        NaN when the run did not record it or it was unknown at the end (the report
        writes NaN as ``null``).

    Raises
    ------
    AnalysisError
        Invalid log, non-finite ``t_start`` or no sample at or after ``t_start``.

    """
    if not isinstance(log, RunLog):
        raise AnalysisError(f'compute_metrics: expected a RunLog, got {type(log).__name__}')
    if not math.isfinite(t_start):
        raise AnalysisError(f't_start must be finite, got {t_start}')
    window = log.t >= t_start
    if not np.any(window):
        raise AnalysisError(f'no samples at or after t_start = {t_start} s '
                            f'(run ends at t = {log.t[-1]:.3f} s)')
    e_pos = tangential_error(log)[window]
    e_force = normal_force_error(log)[window]
    return {
        'rms_position_error_m': float(np.sqrt(np.mean(e_pos ** 2))),
        'max_position_error_m': float(np.max(e_pos)),
        'rms_force_error_n': float(np.sqrt(np.mean(e_force ** 2))),
        'max_force_error_n': float(np.max(np.abs(e_force))),
        'contact_lost_s': contact_lost_time(log),
        'contact_lost_window_s': contact_lost_time(log, t_start),
        'theta_hat_final': [float(v) for v in log.theta_hat[-1]],
        'wall_time_s': float(wall_time_s),
        'sim_time_s': float(log.t[-1] - log.t[0]),
        'stiffness_estimate_n_per_m': math.nan if log.k_hat is None else float(log.k_hat[-1]),
    }


def json_safe(value: Any) -> Any:
    """Replace NaN/inf floats (not valid JSON) by ``None``, recursively."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, list):
        return [json_safe(v) for v in value]
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    return value
