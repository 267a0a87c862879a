"""
Validation of parameter sets, off the control thread (pure numpy + pinocchio).

The node validates every ``ros2 param set`` on its own thread while the control thread
ticks; :class:`SetValidator` therefore computes with pinocchio data of its own (a
``pin.Data`` shared by two threads would mix their states: the margin of one pose
written into the kinematics of a tick). Beyond the schema (params.py), a set must leave
a delay margin (margin.py) of at least ``min_delay_margin`` at the *operating pose*: the
first joint state the runtime received, fixed for its life (the node makes a runtime per
configure). So whether a set is accepted depends on its values, not on where the arm is
at the instant of the set. Margins are cached by the values they depend on, so a set of
f_d, or of values seen before, costs a dictionary look-up.
"""
from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np

from .margin import MarginCache
from ..config.params import build_params, ControllerParams, ParameterValidationError
from ..model.robot_model import RobotModel

__all__ = ['SetValidator', 'model_for_another_thread']


def model_for_another_thread(model: RobotModel) -> RobotModel:
    """Return ``model`` with pinocchio data of its own (the pin.Model is shared, read-only)."""
    other = copy.copy(model)
    other.data = model.model.createData()
    return other


class SetValidator:
    """Validate full parameter sets of one runtime (module docstring)."""

    def __init__(self, model: RobotModel) -> None:
        self.model = model_for_another_thread(model)
        self.operating_pose: np.ndarray | None = None  # set once, by the first joint state
        self._margins = MarginCache()

    def note_pose(self, q: np.ndarray) -> None:
        """Take ``q`` as the operating pose if there is none yet."""
        if self.operating_pose is None:
            self.operating_pose = np.array(q, dtype=float)

    def validate(self, values: dict[str, Any]) -> ControllerParams:
        """
        Validate a full set of values -> ControllerParams, or ParameterValidationError.

        Unchecked for the margin before the first joint state.
        """
        params = build_params(self.model, values)
        need = params.runtime.min_delay_margin
        margin = self.delay_margin(params)
        if need > 0.0 and margin < need:
            raise ParameterValidationError(
                f'the gains leave a delay margin of {margin * 1e3:.2f} ms at the operating '
                f'pose, less than min_delay_margin = {need * 1e3:.2f} ms (lower k_d, k_a or '
                'lambda1, or min_delay_margin)')
        return params

    def delay_margin(self, params: ControllerParams) -> float:
        """
        Return the loop delay ``params`` tolerate at the operating pose, s (margin.py).

        Inf before the first joint state or at a singular pose.
        """
        if self.operating_pose is None:
            return math.inf
        try:
            return self._margins.get(self.model, params.law, self.operating_pose,
                                     params.runtime.force_filter_hz, params.stiffness)
        except (np.linalg.LinAlgError, ValueError):
            return math.inf
