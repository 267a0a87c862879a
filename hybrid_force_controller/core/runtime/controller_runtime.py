"""
What the controller node does between messages, as plain arrays (no rclpy here).

The node converts messages to arrays, calls one method of :class:`ControllerRuntime` (its inputs
and queries: runtime_interface.py; its tick: here), and converts the result back; the offline
engine (engine.py) drives the same object. The runtime owns the latest inputs (latest_inputs.py:
checked, plausible, their staleness, the force filter), the motion (motion.py: the reference along
the surface, the approach along n), the run's times (run_clock.py), the contact state and an
explicit mode (:class:`Mode`):

* ``WAITING``: no joint state or wrench yet (after start-up or a clock restart), or, before
  the first effort, one older than ``state_timeout``: a cell's first samples can come 333 ms
  late (Fast DDS's first send to a reader that just joined), and the one stream's newest then
  looked stale beside the other's first (docs/results.md section 29);
* ``RUNNING``: the law of [1] with its force loop along n (control_law.py);
* ``APPROACH``: contact lost: the normal reference moves into the surface (approach.py);
* ``NO_SURFACE``: the approach travelled ``approach_limit`` without contact: hold, report;
* ``SAFE``: inputs older than ``state_timeout`` (a frozen wrench counts as old), or the
  law failed: stop the tool smoothly and hold it (effort.py ``SafeHold``, continuous with
  the last effort), theta_hat and h frozen. It ends once both inputs have been fresh for
  :data:`SAFE_DWELL_S`: after a stall the backlog of old messages alternates with new ones,
  and a law that ran for the few ms between them met a state 4.5 cm from the last and
  saturated, a command the hold then kept for 100 ms (real time: the paper's arm flung
  20 cm off the surface, or pressed into it at 426-512 N). Fresh is not current: after stale
  inputs, or a stall of the loop, safe mode lasts until each input is current again
  (catch_up.py, (C1)); after a stall nothing is sent meanwhile.

Entering ``RUNNING`` or ``APPROACH`` from ``WAITING`` or ``SAFE`` re-blends the reference from the
arm's position and velocity (no effort jump; after ``SAFE`` the reference goes on from where it
paused). With ``n_estimation``, a run that starts out of contact keeps its reference time at 0 (the
tool held where it is along the surface) until it has touched for :data:`FIRST_TOUCH_S`, and the
reference then goes on from its start (its normal part is the force loop's): n_hat is learnt only
in contact, and a reference that moved along a wrong n before the first touch ran away from the
surface (the paper's line turned 0.3 rad, the start's theta_hat 50 % off: 3 s without contact;
re-blending from the arm at the touch instead doubled the Panda's force error on its tilted plane).
The hand-over from an approach to the force loop aligns the force integral so r is continuous.
theta_hat and h integrate over the time between consecutive *new* joint states, at most
``max_integration_dt``: a tick without a new state recomputes the command and integrates nothing,
and a late state after a gap integrates a bounded step. Every new state also feeds the online
stiffness estimate, which (``stiffness_estimation``) sets the law's k_s (stiffness_loop.py), and
with ``n_estimation`` the estimate of the surface normal (surface.py), whose n_hat then takes n's
place (S, the approach, f_d n, the reference's plane). Times are seconds on the caller's clock.
"""
from __future__ import annotations

import math

import numpy as np

from .catch_up import CatchUp
from .contact import ContactDetector, in_contact
from .effort import CommandStage, SafeHold
from .inputs import InputError
from .latest_inputs import LatestInputs
from .modes import Mode, TickOutput
from .motion import Motion, reference_changed
from .recovery import Recovery
from .run_clock import RunClock
from .runtime_interface import RuntimeInterface
from .steady_tick import SteadyTick
from .surface import SurfaceNormal
from ..config.params import ControllerParams
from ..law.control_law import ApproachRef, ControlError, ControlOutput, HybridForceController
from ..law.orientation import OrientationRef, ToolOrientation
from ..law.reference import Reference
from ..law.set_validation import SetValidator
from ..law.stiffness_loop import StiffnessLoop
from ..model.robot_model import ModelError, RobotModel

__all__ = ['ControllerRuntime', 'InputError', 'Mode', 'TickOutput']


_STATUS = {Mode.RUNNING: 'running', Mode.APPROACH: 'approaching the surface'}
FIRST_TOUCH_S = 0.2  # with n_estimation: the reference's time starts after this long touching
SAFE_DWELL_S = 0.05  # safe mode ends once both inputs have been fresh this long, s
SILENT_STALLS = 2.0  # a stall this many state_timeout long: nothing sent until caught up (C1)
_COUNTERS = ('ticks', 'joint_state_dropped', 'joint_state_implausible',
             'joint_state_clock_implausible', 'wrench_dropped', 'wrench_implausible',
             'wrench_clock_implausible', 'safe_mode_entries', 'control_errors',
             'saturated_ticks', 'clock_restarts', 'approach_entries', 'stale_ticks',
             'late_states', 'stalls', 'singular_ticks')


class ControllerRuntime(RuntimeInterface):
    """Latest inputs + control law + modes and safety logic for one arm."""

    def __init__(self, model: RobotModel, params: ControllerParams) -> None:
        self.model = model
        self.ctrl = HybridForceController(model, params.law)
        self.counters = dict.fromkeys(_COUNTERS, 0)
        self.mode, self.status = Mode.WAITING, 'waiting for inputs'
        self._touch_s = 0.0  # touching, s, before the reference's time starts (_first_touch)
        self.last_safe_reason = ''
        self.last_stall_s = 0.0  # the gap of the last stall, s
        self._in = LatestInputs(model, params.runtime, self.counters)
        self._command = CommandStage(params.runtime.effort_limits)
        self._hold, self._contact = SafeHold(model), ContactDetector()
        self._motion = Motion(params, model.task_index)
        self._motion.ref.kernel = self.ctrl.reference_kernel  # tick_impl compiled: its kernel
        self._clock = RunClock()
        self._stiffness = StiffnessLoop(params.stiffness, params.law.n,
                                        self.ctrl.stiffness_kernels)  # tick_impl compiled: kernels
        self._normal = SurfaceNormal(params, model.task_axes)  # n, or n_hat (surface.py)
        self.orientation = ToolOrientation(params.orientation)  # the 6-D task (orientation.py)
        self.validator = SetValidator(model)
        self.recovery = Recovery(len(params.law.theta_hat0), params.recovery)
        self._restarted = False  # a restart's episode begins at the next start
        self._fresh_since = math.inf  # since when both inputs are fresh (SAFE_DWELL_S)
        self._catch_up = CatchUp()  # after stale inputs or a stall (catch_up.py, (C1))
        # tick_impl compiled: a steady tick in two kernels (steady_tick.py), the rest below
        self._steady = SteadyTick(self) if self.ctrl._tick.fused else None
        self._install(params)

    # ------------------------------------------------------------------ parameters
    def set_params(self, params: ControllerParams) -> None:
        """
        Install a validated set atomically; it takes effect on the next tick.

        A new filter cut-off keeps the filtered force; a new reference (``ref_*``, ``n``,
        ``ref_blend_time``) releases a held point and blends from the current reference;
        a stopped approach (``NO_SURFACE``) starts again from where the tool is.
        """
        changed = reference_changed(self._params, params)
        self._install(params)
        if changed:
            self._motion.replan(params, self.run_time)
        if self.mode == Mode.NO_SURFACE:
            self._enter_approach()

    def _install(self, params: ControllerParams) -> None:
        rt = params.runtime
        if params.orientation.mode != self.orientation.cfg.mode:
            self.orientation.reset()  # a new mode holds the orientation of its start
        self.orientation.configure(params.orientation)
        self._in.moment_wanted = params.orientation.active
        self._params = params
        self.ctrl.set_gains(params.law)
        self._stiffness.configure(params.stiffness, params.law.n, self.ctrl)
        self._in.configure(rt)
        self._command.configure(self.model.joint_names, rt.joints, rt.effort_limits,
                                rt.max_effort_rate)
        self._motion.configure(params)
        self._normal.configure(params, self.ctrl, self._motion)
        self.recovery.configure(params.recovery, params.law.theta_min, params.law.theta_max)
        self._period = 1.0 / rt.rate_hz
        self.ctrl.set_force_setpoint(self._motion.force.value, self._motion.force.fdot)
        if self._steady is not None:
            self._steady.configure(params)

    def _reference_at(self, tau: float) -> Reference:
        """Return the reference at the run's time ``tau`` (n_hat's tangent plane: surface.py)."""
        return self._normal.reference(self._motion, tau, self._in)

    # ------------------------------------------------------------------ tick
    def tick(self, t: float) -> TickOutput:
        """Compute the command for time ``t`` from the latest inputs (steady: steady_tick.py)."""
        out = None if self._steady is None else self._steady.tick(t)
        if out is not None:
            return out
        self.counters['ticks'] += 1
        c = self._clock
        if t < c.t_tick - self._period:  # the clock jumped back (e.g. a restarted /clock)
            self.restart_clock()
        stalled = self._stalled(t)
        c.t_tick = max(c.t_tick, t)
        if self._in.state is None or self._in.wrench is None:
            return self._output(None, Mode.WAITING, 'waiting for joint states and wrench')
        f_W = self._in.filtered_force()
        if self._catch_up.silent and not self._caught_up(t):
            self._fresh_since = math.inf
            return self._safe(f_W, f'catching up after a stall of {self.last_stall_s * 1e3:.0f} '
                              'ms: nothing sent until the inputs are current', t, send=False)
        stale = self._in.stale(t)
        if stale:
            self._fresh_since = math.inf
            if self._command.tau_last is None:  # nothing commanded yet: nothing to make safe
                return self._output(None, Mode.WAITING, f'waiting for fresh inputs ({stale})')
            self._catch_up.begin(silent=False)
            return self._safe(f_W, stale, t)
        if self._catch_up.active and not self._caught_up(t):  # fresh, not current: a backlog
            self._fresh_since = math.inf
            return self._safe(f_W, self.last_safe_reason if self.mode == Mode.SAFE else
                              'catching up: inputs fresh but not yet current', t)
        self._fresh_since = min(self._fresh_since, t)
        if self.mode == Mode.SAFE and t - self._fresh_since < SAFE_DWELL_S:
            return self._safe(f_W, self.last_safe_reason, t)  # fresh, not yet for long
        dt_state, dt_int = self._state_step(stalled or self._restarted)
        if self._motion.force_ramping:
            self.ctrl.set_force_setpoint(*self._motion.force_step(dt_state))
        f_n = float(self._normal.n_W.dot(f_W))
        touching = self._contact.update(f_n, self.ctrl.f_d, self._in.state.t)
        if touching:
            self._motion.note_contact(self._in.kin().x)
        if self._normal.enabled and dt_state > 0.0:  # the normal estimate (surface.py)
            self._normal.update(f_W, self._in.kin(), dt_state, touching, self._motion,
                                self._seated_axis(f_W, touching, dt_state))
        if touching and self._in.tare is not None:
            self._in.tare.abort('the tool touched the surface during the tare')
        self._transitions(touching, stalled, f_W, t)
        self._first_touch(touching, dt_state)
        approach = self._approach_ref(dt_state)
        self._motion.advance_path(dt_state, self.mode == Mode.RUNNING and touching)
        ref = self._reference_at(self.run_time)
        try:
            out = self.ctrl.step(self._in.state.q, self._in.state.qdot, f_W, ref, dt_int,
                                 in_contact=in_contact(f_n, self.ctrl.f_d),
                                 approach=approach, r_bias=self._handover_bias(),
                                 kin=self._in.kin(), adapt=not self.recovery.frozen,
                                 rot=self._rotation(ref, dt_state, touching),
                                 k_w=self._params.orientation.k_w)
        except (ControlError, ModelError, np.linalg.LinAlgError) as exc:
            self.counters['control_errors'] += 1
            return self._safe(f_W, f'control law failed: {exc}', t)
        self.counters['singular_ticks'] += self.ctrl.damped
        if dt_state > 0.0:
            self._normal.feed_stiffness(self._stiffness, self.ctrl, f_n, out.kin.p_W, dt_state,
                                        dt_int, touching)
        self._motion.r_n, self._motion.rdot_n = out.r_n, out.rdot_n
        self._observe(t, f_n, out.e, touching)
        return self._running_output(out.tau, out, ref, f_W)

    def _seated_axis(self, f_W: np.ndarray, touching: bool, dt: float) -> np.ndarray | None:
        """Return the seated pad's axis, the normal's measurement (N7); None: not seated."""
        return self.orientation.seated_axis(self._in.kin().R_W_ee, self._normal.n_W, f_W,
                                            self._in.measured_moment(), dt, touching,
                                            self._params.normal.seat_offset)

    def _rotation(self, ref: Reference, dt: float, touching: bool) -> OrientationRef | None:
        """
        Return the angular reference of the 6-D task (None: orientation_mode free).

        ``moment`` regulates the tilt moments only while touching (out of contact the pad is
        held square to n_hat, as in ``normal``).
        """
        if not self._params.orientation.active:
            return None
        kin, s = self._in.kin(), self._in.state
        return self.orientation.reference(kin.R_W_ee, kin.J_w.dot(s.qdot), self._normal.n_W,
                                          ref.xdot_d_W, self._in.filtered_moment(), dt,
                                          touching)

    def _transitions(self, touching: bool, stalled: bool, f_W: np.ndarray, t: float) -> None:
        """Change mode on contact, a (re)start or a stall; begin the episodes they start."""
        if self.mode in (Mode.WAITING, Mode.SAFE):
            if self._restarted:
                self._restarted = False
                self._begin('restart', t)
            self._start(touching)
        else:
            self._switch(touching, f_W, t)
            if stalled:  # the reference blends from the arm back onto its course
                self._blend_from_arm(correct=True)
        kind = self.recovery.triggered()
        if kind:  # the last tick's force transient or tracking fault
            self._begin(kind, t)

    def _state_step(self, gap: bool) -> tuple[float, float]:
        """Return the time since the last integrated state and the part to integrate (RunClock)."""
        dt, dt_int, why = self._clock.state_step(self._in.state.t, gap, self._period,
                                                 self._params.runtime.max_integration_dt)
        if why:
            self.counters['stale_ticks' if why == 'stale' else 'late_states'] += 1
        return dt, dt_int

    def _start(self, touching: bool) -> None:
        """(Re)start: the reference blends from the arm (after safe mode: back onto its course)."""
        after_safe = self.mode == Mode.SAFE
        if not (self._normal.enabled and not touching and self._clock.t0 is None):
            self._clock.resume(self._in.state.t, after_pause=after_safe)
        self._touch_s = 0.0
        self.mode = Mode.RUNNING
        self._blend_from_arm(correct=after_safe)
        if not touching and self._motion.can_approach:
            self._enter_approach()

    def _first_touch(self, touching: bool, dt: float) -> None:
        """With n_estimation, start the reference's time once touching for FIRST_TOUCH_S."""
        if self._clock.t0 is not None or self.mode != Mode.RUNNING:
            return
        self._touch_s = self._touch_s + dt if touching else 0.0
        if self._touch_s >= FIRST_TOUCH_S:
            self._clock.resume(self._in.state.t, after_pause=False)

    def _blend_from_arm(self, correct: bool = False) -> None:
        """
        Blend the reference from the arm's position and velocity (an approach goes on).

        ``correct`` (a stall, the end of safe mode): back onto the reference's course, a blend
        under way going on (reference.py ``correct_from``); otherwise a new blend into the base.
        """
        kin = self._in.kin()
        pdot_W = np.zeros(3)
        pdot_W[self.model.task_index] = kin.xdot
        self._motion.start_from(self.run_time, kin.p_W, pdot_W, correct)

    def _switch(self, touching: bool, f_W: np.ndarray, t: float) -> None:
        """Contact lost: approach (an episode); contact found: the force loop, r continuous."""
        if self.mode == Mode.RUNNING and not touching and self._motion.can_approach:
            self._begin('contact_loss', t)
            self._enter_approach()
        elif self.mode in (Mode.APPROACH, Mode.NO_SURFACE) and touching:
            r_f, rdot_f = self.ctrl.force_loop_r_n(float(self._normal.n_W @ f_W))
            self._motion.start_handover(self._in.state.t, r_f, rdot_f)
            self.mode = Mode.RUNNING

    def _handover_bias(self) -> tuple[float, float]:
        """Return the approach's part of r and rdot along n still fading (approach.py)."""
        if self.mode != Mode.RUNNING:
            return 0.0, 0.0
        return self._motion.handover_bias(self._in.state.t)

    def _enter_approach(self) -> None:
        self._motion.enter_approach(self._in.kin().x)
        self.counters['approach_entries'] += 1
        self.mode = Mode.APPROACH

    def _approach_ref(self, dt: float) -> ApproachRef | None:
        if self.mode not in (Mode.APPROACH, Mode.NO_SURFACE):
            return None
        ref = self._motion.approach_step(dt, self._in.kin().x)
        if self._motion.approach.exhausted:
            self.mode = Mode.NO_SURFACE
        return ref

    def restart_clock(self) -> None:
        """
        Forget the inputs after a backward time jump and start as after power-up.

        The estimate theta_hat is kept; the force integral and the rate limiter restart.
        """
        self.counters['clock_restarts'] += 1
        self._catch_up.reset()
        self._in.reset()
        self._clock = RunClock()
        self.mode = Mode.WAITING
        self._contact.reset()
        self._command.restart(blend=False)
        self.ctrl.reset(self.ctrl.theta_hat)
        self.orientation.reset()

    def restart(self) -> None:
        """
        Start again from the arm's state on the next tick (after a deactivation).

        The reference re-blends, the force integral and the rate limiter restart, and the
        effort blends from the last one out, which the hardware held (bumpless.py).
        """
        self.mode = Mode.WAITING
        self._catch_up.reset()
        self._command.restart(blend=True)
        self._restarted = True
        self.orientation.reset()

    # ------------------------------------------------------------------ episodes (recovery.py)
    def _stalled(self, t: float) -> bool:
        """
        Say whether the gap since the last tick is a stall (counted).

        One longer than ``state_timeout`` is an episode: the arm may have dropped meanwhile (a
        robot's command watchdog is of that order). Shorter ones, the command held throughout,
        started episodes too, and with the random 10-30 ms hiccups of a loaded machine they
        kept adaptation frozen for most of a run whose trusted estimate was still wrong.
        """
        gap = t - self._clock.t_tick
        if self.mode == Mode.WAITING or not gap > self.recovery.cfg.stall_periods * self._period:
            return False
        self.counters['stalls'] += 1
        self.last_stall_s = gap
        timeout = self._params.runtime.state_timeout
        if gap > timeout:
            self._begin('stall', t)
            if self._command.tau_last is not None:  # silent past a watchdog of that order
                self._catch_up.begin(silent=gap > SILENT_STALLS * timeout)
        return True

    def _caught_up(self, t: float) -> bool:
        """Say whether the catch-up (catch_up.py, (C1)) is over at ``t``."""
        return self._catch_up.done(t, t - self._in.state.t, t - self._in.wrench.t, self._period,
                                   self._params.runtime.state_timeout)

    def _begin(self, kind: str, t: float) -> None:
        """Open an episode; theta_hat takes the estimate it holds (recovery.py), if any."""
        theta = self.recovery.begin(kind, t, self.ctrl.theta_hat)
        if theta is not None:
            self.ctrl.theta_hat = theta.copy()

    def _observe(self, t: float, f_n: float, e: np.ndarray, touching: bool) -> None:
        """Note this tick's errors: calm stretches, and the next tick's episode triggers."""
        self.recovery.note(t, abs(f_n - self.ctrl.f_d), math.sqrt(e.dot(e)),
                           touching and self.mode == Mode.RUNNING, self.ctrl.theta_hat)

    def _safe(self, f_W: np.ndarray, status: str, t: float, send: bool = True) -> TickOutput:
        """
        Hold (effort.SafeHold): a smooth stop, impedance only while the joint state is fresh.

        During a catch-up (C1) a state is fresh only when current: the hold latched on a state
        92 ms old (fresh by state_timeout) pulled the arm back to it at the effort limits.
        ``send`` False: enter (or stay in) safe mode, latched as usual, but send nothing.
        """
        law, s = self._params.law, self._in.state
        age = t - s.t
        fresh = (age <= self._params.runtime.state_timeout
                 and not self._catch_up.holds_stale(age, self._period))
        if self.mode != Mode.SAFE:
            self.counters['safe_mode_entries'] += 1
            self.last_safe_reason = status
            self._begin('safe_mode', t)  # theta_hat may change: latch with the held one
            self._hold.latch(t, f_W, s.q, s.qdot, self.ctrl.theta_hat, self._command.tau_last,
                             fresh)
            self._clock.pause(s.t)  # the reference pauses (_start)
            self._motion.pause_path()
        self.mode = Mode.SAFE
        if not send:
            return self._output(None, Mode.SAFE, status, f_W)
        tau, p_W = self._hold.effort(t, s.q, s.qdot, self.ctrl.theta_hat, law.k_d, law.lambda1,
                                     law.k_null, fresh)
        return self._output(tau, Mode.SAFE, status, f_W, p_W)

    def _running_output(self, tau: np.ndarray, out: ControlOutput, ref: Reference,
                        f_W: np.ndarray) -> TickOutput:
        status = (_STATUS[self.mode] if self.mode != Mode.NO_SURFACE else
                  f'surface not found within approach_limit = '
                  f'{self._params.runtime.approach_limit:g} m: holding')
        return self._output(tau, self.mode, status, f_W, out.kin.p_W, ref, out.e)

    def _output(self, tau: np.ndarray | None, mode: Mode, status: str,
                f_W: np.ndarray | None = None, x_W: np.ndarray | None = None,
                ref: Reference | None = None, e: np.ndarray | None = None) -> TickOutput:
        self.mode, self.status = mode, status
        if tau is not None:
            tau, saturated = self._command(tau, self._clock.t_tick)
            self.counters['saturated_ticks'] += saturated and mode != Mode.SAFE
        x_W = np.zeros(3) if x_W is None else x_W
        f = np.zeros(3) if f_W is None else f_W.copy()
        e_W = np.zeros(3)
        if e is not None:
            e_W[self.model.task_index] = e
        axis = (self.orientation.axis_W(self._in.kin().R_W_ee)
                if self._params.orientation.active and self._in.state is not None else None)
        return TickOutput(tau, mode, x_W, x_W if ref is None else ref.x_d_W, f, self.f_d_W,
                          e_W, self.ctrl.theta_hat.copy(), self._contact.active, status,
                          self._stiffness.k_hat, self._motion.path_progress(),
                          None if ref is None else ref.xdot_d_W, self._normal.n_W, axis)
