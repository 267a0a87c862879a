"""
Tool gravity compensation: the weight a wrist force/torque sensor feels of the tool it carries.

A wrist sensor reports the force the environment *and gravity* exert on the tool (what
MuJoCo's sim and a real sensor read): out of contact it reads the tool's weight. The controller
subtracts it before the law, as ros2_controllers' admittance controller does with its
gravity-compensation CoG: with the tool's mass ``m`` and centre of mass ``c_S`` (sensor
frame), gravity ``g_W`` (base frame) and the sensor frame's rotation ``R_W_S``, the weight in
the sensor frame is ``F_g = m R_W_S^T g_W`` and its torque about the sensor ``c_S x F_g``.

The law uses only the force (its component along n), so the compensation is applied in the
base frame, where it does not depend on the sensor's orientation: the force the tool exerts on
the environment is ``f_W = -R_W_S (F_S - F_g) = -R_W_S F_S + m g_W``. ``c_S`` therefore changes
only the torque, which the law does not use; :func:`tool_weight_S` gives both for a caller that
does. ``m = 0`` (the default) compensates nothing and leaves every computation as it was.
Pure numpy.
"""
from __future__ import annotations

import numpy as np

__all__ = ['tool_weight_S', 'tool_weight_W']


def tool_weight_W(tool_mass: float, g_W: np.ndarray) -> np.ndarray | None:
    """Return ``m g_W``, the force to add to the base-frame f_W; None when ``m`` is 0."""
    if tool_mass == 0.0:
        return None
    return float(tool_mass) * np.asarray(g_W, dtype=float)


def tool_weight_S(tool_mass: float, com_S: np.ndarray, R_W_S: np.ndarray,
                  g_W: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Return the weight's force and torque in the sensor frame, as the sensor reads them.

    Parameters
    ----------
    tool_mass : float
        Mass of the tool, kg.
    com_S : (3,) array
        Its centre of mass in the sensor frame, m.
    R_W_S : (3, 3) array
        Rotation of the sensor frame in the base frame.
    g_W : (3,) array
        Gravity in the base frame, m/s^2.

    Returns
    -------
    tuple of (3,) arrays
        ``F_g = m R_W_S^T g_W`` and ``c_S x F_g``.

    """
    F_g = float(tool_mass) * (np.asarray(R_W_S).T @ np.asarray(g_W, dtype=float))
    return F_g, np.cross(np.asarray(com_S, dtype=float), F_g)
