"""
What goes into and out of the control law besides the reference (control_law.py).

An approach's normal reference (:class:`ApproachRef`), one tick's result
(:class:`ControlOutput`) and the error the law raises on input it cannot act on.
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..model.robot_model import TaskKinematics

__all__ = ['ApproachRef', 'ControlError', 'ControlOutput']


class ControlError(ValueError):
    """The control law met non-finite or inconsistent input it cannot act on."""


class ApproachRef(NamedTuple):
    """
    Normal reference of an approach.

    Position ``x_n = n^T x_ref`` (m), velocity and acceleration along n, base frame.
    """

    x_n: float
    v_n: float
    a_n: float


class ControlOutput(NamedTuple):
    """
    One tick's result.

    It holds the effort (finite, before the runtime's limits), e (task coordinates,
    ``model.task_axes``), the kinematics it used, theta_hat after the update, the force integral
    h, and the normal part of r (m/s) with the mode-specific term of rdot's normal part (m/s^2;
    the rest of rdot is common to both modes).
    """

    tau: np.ndarray
    e: np.ndarray
    kin: TaskKinematics
    theta_hat: np.ndarray
    h: float
    r_n: float
    rdot_n: float
