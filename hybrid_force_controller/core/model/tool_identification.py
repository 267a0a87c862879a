r"""
The tool's mass and centre of mass from a few still poses of a wrist force/torque sensor.

At rest and out of contact the sensor reads the tool's weight (tool_gravity.py) plus its own
bias. In pose ``i`` (the sensor frame's rotation ``R_i = R_W_S``, gravity ``g_W``):

.. math::

    F_i = m R_i^T g_W + b_F, \qquad \tau_i = c_S \times (m R_i^T g_W) + b_\tau

with the mass ``m``, the centre of mass ``c_S`` (sensor frame) and the biases ``b_F``,
``b_tau``. Both are linear in their unknowns, solved by least squares one after the other:

* the force, :math:`[R_i^T g_W \;\; I] [m; b_F] = F_i` over the poses (needs two poses
  whose gravity directions in the sensor frame differ);
* the torque, with :math:`G_i = m R_i^T g_W` now known,
  :math:`[-[G_i]_\times \;\; I] [c_S; b_\tau] = \tau_i` (needs three poses whose gravity
  directions differ: with the bias unknown, two leave the part of ``c_S`` along the
  difference of their ``G_i`` undetermined). Poses that only turn the tool about gravity
  see it from one side: refused (``MIN_SPREAD_RAD``).

The residuals (RMS over the poses of what the fit does not explain) say how well the model
holds: a pose that was not still, a tool that touched, a cable pulling. The result gives
``tool_mass`` and ``tool_com`` for the controller, and the biases for ``wrench_offset``.
Pure numpy; as the sensor-calibration routines of ros2 force-torque drivers do.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ['IdentificationError', 'ToolFit', 'identify_tool']

MIN_SPREAD_RAD = 0.2  # the gravity directions of the poses must span at least this angle


class IdentificationError(ValueError):
    """The poses cannot determine the tool (too few, or gravity seen from too few sides)."""


@dataclass(frozen=True)
class ToolFit:
    """The identified tool; residuals are RMS over the poses (N, N m)."""

    tool_mass: float
    tool_com: np.ndarray        # c_S, m, sensor frame
    force_bias: np.ndarray      # b_F, N, sensor frame
    torque_bias: np.ndarray     # b_tau, N m, sensor frame
    force_residual_n: float
    torque_residual_n_m: float
    poses: int


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _check(R_W_S: np.ndarray, F_S: np.ndarray, tau_S: np.ndarray, g_W: np.ndarray) -> None:
    n = R_W_S.shape[0]
    if R_W_S.shape != (n, 3, 3) or F_S.shape != (n, 3) or tau_S.shape != (n, 3):
        raise IdentificationError(f'need n rotations (n, 3, 3) and n forces and torques (n, 3); '
                                  f'got {R_W_S.shape}, {F_S.shape}, {tau_S.shape}')
    if not (np.isfinite(R_W_S).all() and np.isfinite(F_S).all() and np.isfinite(tau_S).all()):
        raise IdentificationError('the poses hold NaN/Inf')
    if n < 3:
        raise IdentificationError(f'need at least 3 still poses, got {n}')
    g_dirs = np.einsum('nji,j->ni', R_W_S, g_W / np.linalg.norm(g_W))  # R_i^T g, unit
    spread = np.linalg.svd(g_dirs - g_dirs.mean(axis=0), compute_uv=False)
    if spread[1] < np.sin(MIN_SPREAD_RAD) / 2.0:
        raise IdentificationError(
            'the poses see gravity from too few sides (tilt the tool about two axes, by '
            f'{np.degrees(MIN_SPREAD_RAD):.0f} degrees or more): the centre of mass is not '
            'determined')


def identify_tool(R_W_S, F_S, tau_S, g_W=(0.0, 0.0, -9.81)) -> ToolFit:
    """
    Fit the tool's mass, centre of mass and the sensor's biases (module docstring).

    Parameters
    ----------
    R_W_S : (n, 3, 3) array_like
        The sensor frame's rotation in the base frame at each still pose.
    F_S, tau_S : (n, 3) array_like
        The mean force (N) and torque (N m) the sensor read there, sensor frame.
    g_W : (3,) array_like
        Gravity in the base frame, m/s^2.

    Returns
    -------
    ToolFit

    Raises
    ------
    IdentificationError
        Fewer than 3 poses, non-finite values, or gravity seen from too few sides.

    """
    R, F, T = (np.asarray(a, dtype=float) for a in (R_W_S, F_S, tau_S))
    g = np.asarray(g_W, dtype=float)
    _check(R, F, T, g)
    n = R.shape[0]
    g_S = np.einsum('nji,j->ni', R, g)  # R_i^T g_W, each row
    A_f = np.zeros((3 * n, 4))
    A_f[:, 0] = g_S.ravel()
    A_f[:, 1:] = np.tile(np.eye(3), (n, 1))
    x_f, *_ = np.linalg.lstsq(A_f, F.ravel(), rcond=None)
    m, b_F = float(x_f[0]), x_f[1:]
    G = m * g_S
    A_t = np.zeros((3 * n, 6))
    for i in range(n):
        A_t[3 * i:3 * i + 3, :3] = -_skew(G[i])
        A_t[3 * i:3 * i + 3, 3:] = np.eye(3)
    x_t, *_ = np.linalg.lstsq(A_t, T.ravel(), rcond=None)
    r_f = (A_f @ x_f - F.ravel()).reshape(n, 3)
    r_t = (A_t @ x_t - T.ravel()).reshape(n, 3)
    return ToolFit(m, x_t[:3], b_F, x_t[3:],
                   float(np.sqrt(np.mean(np.sum(r_f ** 2, axis=1)))),
                   float(np.sqrt(np.mean(np.sum(r_t ** 2, axis=1)))), n)
