"""
The runtime's face toward the node: inputs handed in, its state read out (no rclpy here).

:class:`RuntimeInterface` is the part of :class:`~.controller_runtime.ControllerRuntime` a node
(or the offline engine) calls between ticks: joint states and wrenches with their stamps (and
reception times), a held point or a planned path, a tare, a parameter set's validation, and the
queries /diagnostics and telemetry read. controller_runtime.py holds the tick and its modes.
Times are seconds on the caller's clock.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from .inputs import InputError, JointSample
from .surface import NormalStatus
from .tare import Tare
from ..config.params import ControllerParams
from ..law.path import PathPlan
from ..law.reference import Reference
from ..law.stiffness_loop import StiffnessStatus

__all__ = ['RuntimeInterface']


class RuntimeInterface:
    """
    Inputs and queries of a runtime (its tick: controller_runtime.py).

    The subclass owns ``_params``, ``_in`` (latest_inputs.py), ``_motion`` (motion.py),
    ``_clock`` (run_clock.py), ``_contact``, ``_stiffness``, ``ctrl`` and ``validator``.
    """

    # ------------------------------------------------------------------ parameters
    @property
    def params(self) -> ControllerParams:
        return self._params

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self._params.runtime.joints

    def validate(self, values: dict[str, Any]) -> ControllerParams:
        """Validate a full set of values (set_validation.py; for the node's thread)."""
        return self.validator.validate(values)

    @property
    def operating_pose(self) -> np.ndarray | None:
        """Return the pose the delay margin is checked at: the first joint state (or None)."""
        return self.validator.operating_pose

    def delay_margin(self, params: ControllerParams | None = None) -> float:
        """Return the loop delay the gains tolerate at the operating pose, s (margin.py)."""
        return self.validator.delay_margin(params or self._params)

    # ------------------------------------------------------------------ inputs
    def on_joint_state(self, names: Sequence[str], q: Sequence[float],
                       qdot: Sequence[float] | None, t: float,
                       t_recv: float | None = None) -> None:
        """
        Store a joint state mapped by name (reordered and extra joints are fine).

        ``t`` is its stamp; ``t_recv`` (optional) the caller's clock when it arrived: the
        stamp is then checked against it and mapped onto it (latest_inputs.py).
        """
        self._in.on_joint_state(names, q, qdot, t, t_recv)
        if self.validator.operating_pose is None and self._in.state is not None:
            self.validator.note_pose(self._in.state.q)

    def on_wrench(self, frame_id: str, force: Sequence[float], t: float,
                  t_recv: float | None = None, torque: Sequence[float] | None = None) -> None:
        """
        Store the force the environment exerts on the tool, in ``frame_id`` (t_recv: above).

        ``torque`` (about the frame's origin) is used by the 6-D task (``orientation_mode``).
        """
        self._in.on_wrench(frame_id, force, t, t_recv, torque)

    def clock_offsets(self) -> dict[str, float]:
        """Return each input stream's measured clock offset, s (NaN before it is measured)."""
        return {k: math.nan if c.offset is None else c.offset for k, c in self._in.clocks.items()}

    def clock_counts(self, counter: str) -> dict[str, int]:
        """
        Return one counter of each input stream's sender clock (sender_clock.py).

        ``relearns``: how often its offset was learned anew; ``startup_refusals``: stamps
        refused in its clock's first second.
        """
        return {k: getattr(c, counter) for k, c in self._in.clocks.items()}

    def start_tare(self, tare: Tare) -> None:
        """
        Begin averaging the raw force reading (tare.py): the sensor's bias, for ``wrench_offset``.

        Aborted at once, saying why, in contact, while the arm moves or before any input.
        """
        if self._contact.active:
            tare.abort('in contact: tare with the tool still and off the surface')
        else:
            self._in.start_tare(tare)

    @property
    def last_fault(self) -> str:
        """Return why the latest rejected input was rejected ('' if none was)."""
        return self._in.last_fault

    def on_reference(self, x_d_W: Sequence[float]) -> None:
        """Hold a point (base frame), blended in; a path ends; a ref_*/n change releases it."""
        x = np.asarray(x_d_W, dtype=float)
        if x.shape != (3,) or not np.all(np.isfinite(x)):
            raise InputError(f'reference must be 3 finite numbers, got {x.tolist()}')
        self._motion.hold(self.run_time, x)

    def on_moment_target(self, m_d_W: Sequence[float]) -> None:
        """Regulate the tilt moments to ``m_d_W`` (N m, base frame; orientation_mode moment)."""
        m = np.asarray(m_d_W, dtype=float)
        if m.shape != (3,) or not np.all(np.isfinite(m)):
            raise InputError(f'moment target must be 3 finite numbers, got {m.tolist()}')
        self.orientation.set_moment_target(m)

    def on_path(self, plan: PathPlan | None, seq: int = 0) -> None:
        """
        Follow a planned path number ``seq`` (law/path.py), blended in (motion.py); None stops.

        Its clock runs only in the force loop in contact (path_run.py); at its end the
        reference holds the last point. A ``ref_*`` or ``n`` change releases it.
        """
        if plan is None:
            self._motion.stop(self.run_time)
        else:
            self._motion.follow(self.run_time, plan, seq)

    # ------------------------------------------------------------------ queries
    @property
    def run_time(self) -> float:
        """Time since the run started, at the latest joint state (the reference's time)."""
        return 0.0 if self._in.state is None else self._clock.tau(self._in.state.t)

    @property
    def state_stamp(self) -> float:
        """Stamp of the latest joint state on the caller's clock, s (-inf before the first)."""
        return -math.inf if self._in.state is None else self._in.state.t

    @property
    def joint_sample(self) -> JointSample | None:
        """Return the latest accepted joint state (model order, stamp on the caller's clock)."""
        return self._in.state

    @property
    def wrench_stamp(self) -> float:
        """Stamp of the latest accepted wrench on the caller's clock, s (NaN before the first)."""
        w = self._in.wrench
        return math.nan if w is None else w.t

    @property
    def f_d_W(self) -> np.ndarray:
        """Return the desired force f_d n, base frame (f_d ramped to a new value: motion.py)."""
        return self._motion.f_d_W

    @property
    def theta_hat(self) -> np.ndarray:
        return self.ctrl.theta_hat

    @property
    def in_contact(self) -> bool:
        """Return the contact state (hysteresis on the filtered normal force)."""
        return self._contact.active

    def stiffness_status(self) -> StiffnessStatus:
        """
        Return the stiffness estimate and the k_s / lambda2 in use, for /diagnostics.

        /diagnostics reports WARN when ``near_k_max``.
        """
        return self._stiffness.status(self.ctrl)

    def desired_position(self, t: float) -> np.ndarray:
        """Return the reference position at time ``t`` on the caller's clock (base frame)."""
        t0 = self._clock.t0
        return self._normal.position(self._motion, 0.0 if t0 is None else t - t0, self._in)

    def reference(self, t: float) -> Reference:
        """Return the reference at time ``t`` on the caller's clock (a path: at its clock)."""
        t0 = self._clock.t0
        return self._reference_at(0.0 if t0 is None else t - t0)

    def normal_status(self) -> NormalStatus:
        """Return the normal in use and the estimate's state, for /diagnostics."""
        return self._normal.status()
