"""The runtime's modes and what one tick gives the node (pure numpy)."""
from __future__ import annotations

from dataclasses import dataclass
from enum import Enum
import math

import numpy as np

from .path_run import IDLE, PathProgress

__all__ = ['Mode', 'TickOutput']


class Mode(str, Enum):
    """The runtime's state (its value is what /diagnostics shows)."""

    WAITING = 'waiting'
    RUNNING = 'running'
    APPROACH = 'approach'
    NO_SURFACE = 'no_surface'
    SAFE = 'safe'


@dataclass
class TickOutput:
    """
    One tick for the node to publish.

    3-D vectors are in the base frame; ``tau`` is in the order of ``params.runtime.joints``, None
    while waiting; ``k_hat`` is the stiffness estimate, N/m, NaN while unknown; ``path`` the
    progress of a user's path (path_run.py); ``xdot_d_W`` the reference's velocity (None
    while not running); ``n_W`` the surface normal in use (the ``n`` parameter, or the
    estimate n_hat with ``n_estimation``; runtime/surface.py); ``axis_W`` the tool's axis
    (``tool_axis`` turned into the base frame) while its orientation is controlled, else None.
    """

    tau: np.ndarray | None
    mode: Mode
    x_W: np.ndarray
    x_d_W: np.ndarray
    f_W: np.ndarray
    f_d_W: np.ndarray
    e_W: np.ndarray
    theta_hat: np.ndarray
    in_contact: bool
    status: str = ''
    k_hat: float = math.nan
    path: PathProgress = IDLE
    xdot_d_W: np.ndarray | None = None
    n_W: np.ndarray | None = None
    axis_W: np.ndarray | None = None
