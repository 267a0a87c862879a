"""
The runtime's latest inputs: checked samples, their staleness, the filtered force (no rclpy).

:class:`LatestInputs` keeps the newest joint state and wrench that passed the checks of
inputs.py, computes the kinematics once per joint state, rotates each new wrench into the base
frame (less the tool's weight, ``tool_mass``: tool_gravity.py) and low-pass filters it over the
wrench stamps (with ``moment_wanted``, the 6-D task, its torque too, less the weight's about
``tool_com``), and says when the inputs are too old to act on. Every reading first loses the
sensor's bias (``wrench_offset``, sensor frame), which a tare (tare.py) measures from the raw
readings. Rejected samples are counted in
the caller's counters and raise the typed error. Times are seconds on the caller's clock.

Given the reception time ``t_recv`` of a message (the caller's clock when it arrived), its
stamp is first checked against that clock and mapped onto it by the stream's
:class:`~.sender_clock.SenderClock` (``max_clock_skew``; a sensor whose clock is off by a few
seconds works). Without it (``t_recv`` None: the offline engine) stamps are used as they are.
"""
from __future__ import annotations

import math
from typing import Sequence

import numpy as np

from .filters import LowPassFilter
from .inputs import (ImplausibleJointState, ImplausibleWrench, InputError, JointInput,
                     JointSample, WrenchGate, WrenchSample)
from .sender_clock import ImplausibleStamp, SenderClock
from .tare import still, Tare
from ..config.params import RuntimeConfig
from ..model.robot_model import RobotModel, TaskKinematics
from ..model.tool_gravity import tool_weight_S, tool_weight_W

__all__ = ['LatestInputs']


class LatestInputs:
    """Newest joint state and wrench, kinematics once per state, f_W filtered, staleness."""

    def __init__(self, model: RobotModel, rt: RuntimeConfig, counters: dict[str, int]) -> None:
        self.model, self.counters = model, counters
        self.last_fault = ''
        self.gate = WrenchGate(model.model.existFrame, 0.0, 0.0)
        self._js_clock, self._wrench_clock = SenderClock('joint state'), SenderClock('wrench')
        self.clocks = {'joint_state': self._js_clock, 'wrench': self._wrench_clock}
        self.filter = LowPassFilter(rt.force_filter_hz)
        self.state: JointSample | None = None
        self.wrench: WrenchSample | None = None
        self._kin_of: JointSample | None = None  # the state _kin_cached belongs to
        self._kin_cached: TaskKinematics | None = None
        self._wrench_prev_t, self._new_wrench = -math.inf, False
        self._torque_S: np.ndarray | None = None  # the accepted wrench's torque (None: none)
        self._moment = LowPassFilter(rt.force_filter_hz)  # m_W, filtered as f_W
        self.moment_wanted = False  # the torque is decoded and filtered (the 6-D task)
        self.tare: Tare | None = None  # a tare under way (it takes the raw readings)
        self.configure(rt)

    def configure(self, rt: RuntimeConfig) -> None:
        """Install the joint order, wrench limits and period of a validated configuration."""
        self._rt = rt
        self._joints = JointInput(self.model.joint_names, rt.joints)
        # a jump is refused up to 2 state_timeout after the last accepted state: a burst
        # longer than state_timeout is safe mode (stale), then the new position is adopted
        self._joints.configure_checks(self.model.velocity_limits, rt.joint_velocity_margin,
                                      rt.max_joint_jump, rt.max_joint_acceleration,
                                      2.0 * rt.state_timeout)
        self.gate.configure(rt.wrench_limit, rt.wrench_rate_limit)
        for clock in self.clocks.values():
            clock.configure(rt.max_clock_skew, rt.state_timeout, 2.0 * rt.state_timeout,
                            0.5 / rt.rate_hz)
        self._period = 1.0 / rt.rate_hz
        R_W_root = self.model.base_from_root(np.zeros(3), np.eye(3), np.zeros((3, 0)))[1]
        g_W = R_W_root @ self.model.model.gravity.linear
        self._weight_W = tool_weight_W(rt.tool_mass, g_W)  # None: no tool to compensate
        self._g_W, self._tool = g_W, (rt.tool_mass, rt.tool_com)
        offset = rt.wrench_offset  # the sensor's bias (0: none, nothing subtracted)
        self._offset = tuple(float(c) for c in offset) if np.any(offset) else None
        if rt.force_filter_hz != self.filter.cutoff_hz:
            value, ready = self.filter.value.copy(), self.filter.ready
            self.filter = LowPassFilter(rt.force_filter_hz)
            if ready:
                self.filter.update(value, 0.0)
            self._moment = LowPassFilter(rt.force_filter_hz)

    def reset(self) -> None:
        """Forget every input (a backward time jump)."""
        self.state = self.wrench = None
        self.gate.reset()
        self.filter.reset()
        self._moment.reset()
        for clock in self.clocks.values():
            clock.reset()

    def on_joint_state(self, names: Sequence[str], q: Sequence[float],
                       qdot: Sequence[float] | None, t: float,
                       t_recv: float | None = None) -> None:
        """Store a joint state mapped by name (reordered and extra joints are fine)."""
        try:
            if t_recv is not None:
                t = self._js_clock.receive(t, t_recv)
            self.state = self._joints.sample(names, q, qdot, t, self.state)
        except ImplausibleStamp as exc:
            self._fault('joint_state_clock_implausible', exc)
        except ImplausibleJointState as exc:
            self._fault('joint_state_implausible', exc)
        except InputError as exc:
            self._fault('joint_state_dropped', exc)

    def on_wrench(self, frame_id: str, force: Sequence[float], t: float,
                  t_recv: float | None = None, torque: Sequence[float] | None = None) -> None:
        """
        Store the force (and torque) the environment exerts on the tool, in ``frame_id``.

        The torque is about the frame's origin; a reading whose torque is not 3 finite numbers
        is refused whole (the sensor is broken).
        """
        raw = force
        if self._offset is not None and len(force) == 3:
            ox, oy, oz = self._offset
            force = (force[0] - ox, force[1] - oy, force[2] - oz)
        try:
            if torque is not None:
                torque = _torque(torque) if self.moment_wanted else None
            if t_recv is not None:
                t = self._wrench_clock.receive(t, t_recv)
            sample = self.gate.check(frame_id, force, t)
        except ImplausibleStamp as exc:
            self._fault('wrench_clock_implausible', exc)
        except ImplausibleWrench as exc:
            self._fault('wrench_implausible', exc)
        except InputError as exc:
            self._fault('wrench_dropped', exc)
        self._wrench_prev_t = -math.inf if self.wrench is None else self.wrench.t
        self.wrench, self._new_wrench = sample, True
        self._torque_S = torque
        if self.tare is not None:
            self._feed_tare(raw, t)

    def start_tare(self, tare: Tare) -> None:
        """Begin a tare at the next wrench that has a joint state beside it (_feed_tare)."""
        self.tare = tare

    def _feed_tare(self, raw: Sequence[float], t: float) -> None:
        """
        Give the tare one raw reading; its first takes the tool's weight as the sensor sees it.

        A tare begun before any joint state waits for one (a tare right after configure);
        the arm moving aborts it, saying so.
        """
        tare, s = self.tare, self.state
        if s is None:
            return
        if not still(s.qdot):
            tare.abort(f'the arm is moving (|qdot| up to {np.abs(s.qdot).max():.3g} rad/s)')
        elif tare.samples == 0 and self._weight_W is not None:
            R = self._rotation(self.wrench.frame_id)
            tare.weight_S = self._weight_W if R is None else R.T.dot(self._weight_W)
        tare.add(float(raw[0]), float(raw[1]), float(raw[2]), t)
        if not tare.running:
            self.tare = None

    def _rotation(self, frame: str) -> np.ndarray | None:
        """Return R_W_frame at the latest state (None for the base frame)."""
        model = self.model
        return (None if frame == model.base_link else self.kin().R_W_ee
                if frame == model.end_effector_link
                else model.frame_rotation(self.state.q, frame))

    def _fault(self, counter: str, exc: InputError) -> None:
        self.counters[counter] += 1
        self.last_fault = str(exc)
        raise exc

    def kin(self) -> TaskKinematics:
        """Return the kinematics of the latest joint state, computed once per state."""
        s = self.state
        if self._kin_of is not s:
            self._kin_cached, self._kin_of = self.model.kinematics(s.q, s.qdot), s
        return self._kin_cached

    def filtered_force(self) -> np.ndarray:
        """Return f_W: the newest wrench in the base frame, low-pass filtered over its stamps."""
        if self._new_wrench:
            w = self.wrench
            R = self._rotation(w.frame_id)
            f_W = -w.F_S if R is None else -R.dot(w.F_S)  # environment.f_W_from_sensor_wrench
            if self._weight_W is not None:  # the sensor feels the tool's weight: remove it
                f_W = f_W + self._weight_W
            gap = w.t - self._wrench_prev_t
            gap = gap if 0.0 < gap < 10.0 * self._period else self._period
            self.filter.update(f_W, gap)
            if self._torque_S is not None:
                self._moment.update(self._moment_W(R, self._torque_S), gap)
            self._new_wrench = False
        return self.filter.value

    def _moment_W(self, R: np.ndarray | None, T_S: np.ndarray) -> np.ndarray:
        """
        Return the moment the tool exerts on the part about the sensor's origin, W.

        ``m_W = -R_W_S (T_S - c_S x F_g)``: the sensor's torque less the tool weight's
        (tool_gravity.py; 0 without a tool mass).
        """
        mass, com_S = self._tool
        if mass != 0.0:
            R_W_S = np.eye(3) if R is None else R
            T_S = T_S - tool_weight_S(mass, com_S, R_W_S, self._g_W)[1]
        return -T_S if R is None else -R.dot(T_S)

    def measured_moment(self) -> np.ndarray | None:
        """Return m_W filtered as f_W, or None before any torque (after filtered_force)."""
        return self._moment.value if self._moment.ready else None

    def filtered_moment(self) -> np.ndarray:
        """Return m_W filtered as f_W (zeros before any torque; after filtered_force)."""
        m_W = self.measured_moment()
        return np.zeros(3) if m_W is None else m_W

    def stale(self, t: float) -> str:
        """Say why the inputs are too old to act on at ``t`` ('' when they are fresh)."""
        timeout = self._rt.state_timeout
        if t - self.state.t > timeout:
            return 'joint states older than state_timeout: safe mode'
        t_value = self.wrench.t
        if self._rt.reject_frozen_wrench and self.gate.frozen_since is not None:
            t_value = self.gate.frozen_since
        if t - t_value > timeout:
            return ('wrench frozen (identical readings) or implausible for longer than '
                    'state_timeout: safe mode' if t - self.wrench.t <= timeout else
                    'wrench older than state_timeout: safe mode')
        return ''


def _torque(torque: Sequence[float]) -> np.ndarray:
    """Return a wrench's torque as an array; InputError unless 3 finite numbers."""
    T = np.array([float(c) for c in torque])
    if T.shape != (3,) or not np.all(np.isfinite(T)):
        raise InputError(f'wrench torque is not 3 finite numbers: {list(torque)}')
    return T
