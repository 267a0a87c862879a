"""What the controller node does between messages, as plain arrays (no rclpy here).

The node converts messages to arrays, calls one method of :class:`ControllerRuntime`, and
converts the result back. This module owns the latest inputs, their staleness, the force
filter, the reference, the safe mode and the counters; the control law itself is
:class:`~hybrid_force_controller.core.control_law.HybridForceController`. Times are seconds on
the caller's clock (node time, so ``use_sim_time`` works); nothing here reads a clock.

Safe mode (inputs older than ``state_timeout``) holds the arm: ``tau = g_hat(q) + J^T f``
(adapted gravity torque plus the last contact force, so the arm stays where it is against
the surface), and, only while the joint velocity is fresh, ``- k_d J^T J qdot``
(``- k_null qdot`` too on redundant arms); a stale velocity is never damped, since it would
act as a constant push. Clamped to the effort limits; theta_hat and h are frozen. On
recovery the reference restarts at the arm's position and velocity and blends back into
the sine over ``ref_blend_time``, so the effort does not jump; a parameter change of the
reference or a new held point blends the same way (reference.BlendedReference).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .control_law import ControlError, HybridForceController, in_contact
from .environment import f_W_from_sensor_wrench
from .filters import LowPassFilter
from .params import ControllerParams, build_controller_params
from .reference import BlendedReference, SineReference
from .robot_model import ModelError, RobotModel

__all__ = ['ControllerRuntime', 'InputError', 'TickOutput', 'params_for_model']


def params_for_model(model: RobotModel, values: dict[str, Any]) -> ControllerParams:
    """Validate parameter values against the schema and ``model`` (joints default to the
    model's joints; theta bounds default to the parameter set's)."""
    ps = model.parameter_set
    return build_controller_params(
        {'joints': list(model.joint_names), **values}, p=len(model.theta_nominal),
        n_joints=model.n, task_axes=model.task_axes, theta_nominal=model.theta_nominal,
        urdf_effort_limits=model.effort_limits, theta_bounds=(ps.theta_min, ps.theta_max))


class InputError(ValueError):
    """A message the controller cannot use; the text names the problem."""


@dataclass
class TickOutput:
    """One tick for the node to publish (3-D vectors in the base frame)."""

    tau: np.ndarray | None
    mode: str
    x_W: np.ndarray
    x_d_W: np.ndarray
    f_W: np.ndarray
    f_d_W: np.ndarray
    e_W: np.ndarray
    theta_hat: np.ndarray
    theta_names: tuple[str, ...]
    in_contact: bool
    counters: dict[str, int] = field(default_factory=dict)
    status: str = ''


class ControllerRuntime:
    """Latest inputs + control law + safety logic for one arm."""

    def __init__(self, model: RobotModel, params: ControllerParams) -> None:
        self.model = model
        self.ctrl = HybridForceController(model, params)
        self.counters = {'joint_state_dropped': 0, 'wrench_dropped': 0, 'ticks': 0,
                         'safe_mode_entries': 0, 'control_errors': 0, 'saturated_ticks': 0,
                         'clock_restarts': 0}
        self._q = self._qdot = None
        self._t_state = self._t_wrench = self._t_wrench_prev = self._t_tick = -np.inf
        self._F_S = np.zeros(3)  # force of the environment on the tool, sensor frame S
        self._wrench_frame_id: str | None = None
        self._new_wrench = False
        self._t0: float | None = None
        self.mode = 'waiting'
        self._filter = LowPassFilter(params.force_filter_hz)
        self._ref = BlendedReference(_sine(params), params.n, params.ref_blend_time)
        self._install(params)

    @property
    def params(self) -> ControllerParams:
        return self.ctrl.params

    @property
    def joint_names(self) -> tuple[str, ...]:
        return self.params.joints

    def validate(self, values: dict[str, Any]) -> ControllerParams:
        """Full set of parameter values -> ControllerParams (ParameterValidationError)."""
        return params_for_model(self.model, values)

    def set_params(self, params: ControllerParams) -> None:
        """Install a validated set atomically; it takes effect on the next tick.

        A new filter cut-off keeps the filtered force; a new reference (``ref_*``, ``n``,
        ``ref_blend_time``) releases a held point and blends from the current reference.
        """
        old = self.params
        if params.force_filter_hz != old.force_filter_hz:
            value, ready = self._filter.value.copy(), self._filter.ready
            self._filter = LowPassFilter(params.force_filter_hz)
            if ready:
                self._filter.update(value, 0.0)
        changed = any(not np.array_equal(getattr(params, k), getattr(old, k)) for k in
                      ('ref_center', 'ref_amplitude', 'ref_omega', 'ref_blend_time', 'n'))
        self._install(params)
        if changed:
            self._ref.switch(self._tau(), sine=_sine(params), release=True, n_W=params.n,
                             t_blend=params.ref_blend_time)

    def _install(self, params: ControllerParams) -> None:
        unknown = [j for j in params.joints if j not in self.model.joint_names]
        if unknown:
            raise InputError(f'joints not in the robot model: {unknown}')
        self._cmd_order = [self.model.joint_names.index(j) for j in params.joints]
        self.ctrl.set_params(params)
        self._period = 1.0 / params.rate_hz
        self._f_d_W = params.f_d * params.n

    def _tau(self) -> float:
        """Run time of the latest joint state (the reference's time)."""
        return 0.0 if self._t0 is None else self._t_state - self._t0

    # ------------------------------------------------------------------ inputs
    def on_joint_state(self, names: Sequence[str], q: Sequence[float],
                       qdot: Sequence[float] | None, t: float) -> None:
        """Store a joint state mapped by name (reordered and extra joints are fine)."""
        try:
            if t < self._t_state:
                raise InputError(f'joint state stamp {t:.6f} is older than the last one '
                                 f'{self._t_state:.6f}')
            self._q, self._qdot = self._map_joints(names, q, qdot)
        except InputError:
            self.counters['joint_state_dropped'] += 1
            raise
        self._t_state = t

    def _map_joints(self, names, q, qdot) -> tuple[np.ndarray, np.ndarray]:
        if len(q) != len(names) or (qdot is not None and len(qdot) not in (0, len(names))):
            raise InputError('joint state: names, positions and velocities differ in length')
        pos = {n: i for i, n in enumerate(names)}
        missing = [j for j in self.params.joints if j not in pos]
        if missing:
            raise InputError(f'joint state lacks controlled joint(s) {missing}')
        if qdot is None or not len(qdot):
            raise InputError('joint state has no velocities')
        idx = [pos[j] for j in self.model.joint_names]
        q_arr, v_arr = np.asarray(q, dtype=float)[idx], np.asarray(qdot, dtype=float)[idx]
        if not (np.all(np.isfinite(q_arr)) and np.all(np.isfinite(v_arr))):
            raise InputError('joint state holds NaN/Inf')
        return q_arr, v_arr

    def on_wrench(self, frame_id: str, force: Sequence[float], t: float) -> None:
        """Store the force the environment exerts on the tool, expressed in ``frame_id``."""
        F_S = np.asarray(force, dtype=float)
        problem = None
        if F_S.shape != (3,) or not np.all(np.isfinite(F_S)):
            problem = f'wrench holds NaN/Inf or is not 3-D: {F_S.tolist()}'
        elif not self.model.model.existFrame(frame_id or ' '):
            problem = f"wrench frame '{frame_id}' is not a frame of the robot model"
        elif t < self._t_wrench:
            problem = f'wrench stamp {t:.6f} is older than the last one {self._t_wrench:.6f}'
        if problem:
            self.counters['wrench_dropped'] += 1
            raise InputError(problem)
        self._t_wrench_prev, self._t_wrench = self._t_wrench, t
        self._F_S, self._wrench_frame_id, self._new_wrench = F_S, frame_id, True

    def on_reference(self, x_d_W: Sequence[float]) -> None:
        """Hold a user reference point (base frame) instead of the sine, blended in.

        Any later change of a ``ref_*`` parameter (or ``n``) releases it."""
        x = np.asarray(x_d_W, dtype=float)
        if x.shape != (3,) or not np.all(np.isfinite(x)):
            raise InputError(f'reference must be 3 finite numbers, got {x.tolist()}')
        self._ref.switch(self._tau(), x_hold_W=x)

    # ------------------------------------------------------------------ tick
    def tick(self, t: float) -> TickOutput:
        """Compute the command for time ``t`` from the latest inputs."""
        self.counters['ticks'] += 1
        period = self._period
        if t < self._t_tick - period:  # the clock jumped back (e.g. a restarted /clock)
            self.restart_clock()
        dt = min(max(t - self._t_tick, 0.1 * period), 10.0 * period)
        self._t_tick = max(self._t_tick, t)
        if self._q is None or self._wrench_frame_id is None:
            return self._output(None, 'waiting', None, 'waiting for joint states and wrench')
        f_W = self._filtered_force(dt)
        if t - min(self._t_state, self._t_wrench) > self.params.state_timeout:
            return self._safe(f_W, 'inputs older than state_timeout: safe mode', t)
        if self.mode != 'running':
            self._start()
        ref = self._ref(self._tau())
        try:
            out = self.ctrl.step(self._q, self._qdot, f_W, ref, dt)
        except (ControlError, ModelError, np.linalg.LinAlgError) as exc:
            self.counters['control_errors'] += 1
            return self._safe(f_W, f'control law failed: {exc}', t)
        self.mode = 'running'
        self.counters['saturated_ticks'] += int(out.saturated)
        return self._output(out.tau, 'running', f_W, 'running', self.ctrl.last_kin.p_W,
                            ref.x_d_W, out.e)

    def restart_clock(self) -> None:
        """Forget the input stamps after a backward time jump and start as after power-up
        (keeping theta_hat; the force integral and the rate limiter restart)."""
        self.counters['clock_restarts'] += 1
        self._q = self._qdot = self._wrench_frame_id = None
        self._t_state = self._t_wrench = self._t_wrench_prev = self._t_tick = -np.inf
        self._t0 = None
        self.mode = 'waiting'
        self._filter.reset()
        self.ctrl.reset(self.ctrl.theta_hat)

    def _filtered_force(self, dt: float) -> np.ndarray:
        """f_W: the newest wrench in the base frame, low-pass filtered over wrench stamps."""
        if self._new_wrench:
            frame = self._wrench_frame_id
            R = None if frame == self.model.base_link else self.model.frame_rotation(self._q,
                                                                                   frame)
            f_W = -self._F_S if R is None else f_W_from_sensor_wrench(R, self._F_S)
            gap = self._t_wrench - self._t_wrench_prev
            self._filter.update(f_W, gap if 0.0 < gap < 10.0 * self._period else dt)
            self._new_wrench = False
        return self._filter.value

    def _start(self) -> None:
        """(Re)start tracking: the reference blends from the arm's position and velocity."""
        self._t0 = self._t_state if self._t0 is None else self._t0
        kin = self.model.kinematics(self._q, self._qdot)
        pdot_W = np.zeros(3)
        pdot_W[self.model.task_index] = kin.xdot
        self._ref.start_from(self._tau(), kin.p_W, pdot_W)

    def _safe(self, f_W: np.ndarray, status: str, t: float) -> TickOutput:
        """Hold: gravity compensation plus the last contact force, damping only with a
        fresh velocity; adaptation and force loop frozen; effort and rate limits apply."""
        if self.mode != 'safe':  # the force at entry is held: adding the live force would
            self.counters['safe_mode_entries'] += 1  # cancel the surface's reaction (with
            self._f_hold = f_W[self.model.task_index].copy()  # stale q: positive feedback)
        self.mode = 'safe'
        kin = self.model.kinematics(self._q, self._qdot)
        z = np.zeros(self.model.n)
        Y_g, tau_0 = self.model.regressor_affine(self._q, z, z, z)
        g_hat = Y_g @ self.ctrl.theta_hat + (0.0 if tau_0 is None else tau_0)
        tau = g_hat + kin.J_ee.T @ self._f_hold
        if t - self._t_state <= self.params.state_timeout:  # the velocity is fresh: damp it
            tau -= self.params.k_d * (kin.J_ee.T @ kin.xdot)
            if self.model.redundant:
                tau -= self.params.k_null * self._qdot
        if not np.all(np.isfinite(tau)):
            tau = np.zeros(self.model.n)
        return self._output(self.ctrl.limit(tau), 'safe', f_W, status, kin.p_W.copy())

    def _output(self, tau, mode: str, f_W, status: str, x_W=None, x_d_W=None,
                e=None) -> TickOutput:
        p = self.params
        x_W = np.zeros(3) if x_W is None else x_W
        f = np.zeros(3) if f_W is None else f_W.copy()
        e_W = np.zeros(3)
        if e is not None:
            e_W[self.model.task_index] = e
        tau = None if tau is None else tau[self._cmd_order]
        return TickOutput(tau, mode, x_W, x_W if x_d_W is None else x_d_W, f, self._f_d_W,
                          e_W, self.ctrl.theta_hat.copy(), self.model.theta_names,
                          in_contact(float(p.n @ f), p.f_d), dict(self.counters), status)


def _sine(params: ControllerParams) -> SineReference:
    return SineReference(params.ref_center, params.ref_amplitude, params.ref_omega)
