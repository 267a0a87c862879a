"""
The one loop engine: :class:`~.runtime.ControllerRuntime` against a plant, offline.

Every offline run (``paper``, ``bench``, the closed-loop tests) goes through
:func:`run_loop`, so they all exercise the node's own logic (inputs, filter, reference,
modes, safe hold). The engine replays what happens between two processes over DDS with a
:class:`~.timing.TimingModel`: the plant steps at ``period`` on its own clock and publishes
its state (joint state and wrench, one stamp); each message reaches the controller after a
latency; the controller ticks on a timer (or on each new state) and its effort reaches the
plant after a latency; either process can stall (a scheduler hiccup, SIGSTOP), during
which it neither publishes nor reads, while the plant's physics goes on with the command
it holds, for at most ``command_timeout``: then the plant applies zero effort, as the sim's
watchdog and a bare torque interface do (the arm falls), or brakes (``watchdog_action``, as a
Franka's reflex stops the arm), also while the plant's own
process stalls (the watchdog of an arm's firmware does not wait for its driver; before, the
held command drove the paper's arm 9 cm along the surface in a 300 ms stall). Times are
integer nanoseconds inside, so equal times compare exactly; ``TimingModel.lockstep(d)``
reproduces the old "d periods of delay" model. Pure numpy.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math
from typing import Any, Callable, Protocol, Sequence

import numpy as np

from .environment import sensor_wrench_from_f_W
from .timing import Schedule, TimingModel
from ..runtime.controller_runtime import ControllerRuntime, Mode

__all__ = ['COMMAND_TIMEOUT_S', 'Event', 'LoopEngine', 'LoopLog', 'Plant', 'run_loop',
           'WATCHDOG_ACTIONS']

COMMAND_TIMEOUT_S = 0.1  # the plant's watchdog, as the sim node's default command_timeout
WATCHDOG_ACTIONS = ('zero', 'brake')  # what the plant does after it (the sim node's choices)


class Plant(Protocol):
    """What the engine needs of a plant (``simulator.ArmSimulator`` is one)."""

    t: float

    def step(self, tau: np.ndarray, dt: float) -> Any: ...

    def measure(self) -> Any: ...

    def hold(self, dt: float) -> Any: ...


@dataclass(frozen=True)
class Event:
    """``action(runtime, plant)`` at plant time ``t`` (a parameter set, a surface move...)."""

    t: float
    action: Callable[[ControllerRuntime, Any], None]


@dataclass
class LoopLog:
    """
    Log of a run, one entry per plant step.

    Time, state, forces (3-D, base frame), reference, effort, theta_hat, the stiffness
    estimate ``k_hat`` (N/m, NaN while unknown) and the normal the controller used ``n_hat_W``
    (its ``n``, or the estimate with ``n_estimation``; zero before the first tick).
    """

    t: np.ndarray
    x_W: np.ndarray
    x_d_W: np.ndarray
    f_W: np.ndarray
    f_true_W: np.ndarray
    f_d_W: np.ndarray
    theta_hat: np.ndarray
    tau: np.ndarray
    mode: list[str]
    commands: int
    ticks: int
    delays_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    tick_ns: np.ndarray = field(default_factory=lambda: np.zeros(0))
    k_hat: np.ndarray = field(default_factory=lambda: np.zeros(0))
    n_hat_W: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))


@dataclass
class _Channel:
    """Messages in flight: (arrival ns, payload), delivered in order (DDS reliable)."""

    queue: list = field(default_factory=list)
    last_arrival: int = -1

    def send(self, arrival: int, payload: Any) -> None:
        arrival = max(arrival, self.last_arrival)
        self.last_arrival = arrival
        self.queue.append((arrival, payload))

    def newest(self, now: int) -> Any:
        """Return the newest payload arrived by ``now`` (older ones are dropped: KEEP_LAST 1)."""
        got = None
        while self.queue and self.queue[0][0] <= now:
            got = self.queue.pop(0)[1]
        return got


class LoopEngine:
    """
    Runtime, plant and timing over one horizon; :meth:`step` advances one plant period.

    ``wrench_frame`` is the frame the sensor reports in (default the end effector, like a
    wrist sensor). ``input_hook(t, (q, qdot, F_S))`` may return a corrupted tuple, or None
    to drop the message (fault injection). ``clock_ns`` (e.g. ``time.perf_counter_ns``,
    injected by a benchmark) times every ``runtime.tick`` into ``LoopLog.tick_ns``.
    ``command_timeout`` (s, plant time; ``math.inf``: never) is the plant's watchdog: a
    command older than this is replaced by zero effort (``watchdog_action`` ``zero``: the arm
    falls) or by the brakes (``brake``: the arm stops and holds until the next command), as
    the sim node's ``watchdog_action`` does.
    """

    def __init__(self, runtime: ControllerRuntime, plant: Plant, horizon: float,
                 timing: TimingModel = TimingModel(), events: Sequence[Event] = (),
                 wrench_frame: str | None = None,
                 input_hook: Callable[[float, Any], Any] | None = None,
                 clock_ns: Callable[[], int] | None = None,
                 command_timeout: float = COMMAND_TIMEOUT_S,
                 watchdog_action: str = 'zero') -> None:
        if not command_timeout > 0.0:
            raise ValueError(f'command_timeout must be > 0, got {command_timeout!r}')
        if watchdog_action not in WATCHDOG_ACTIONS:
            raise ValueError(f'watchdog_action must be one of {list(WATCHDOG_ACTIONS)}, '
                             f'got {watchdog_action!r}')
        self._brake = watchdog_action == 'brake'
        self.runtime, self.plant = runtime, plant
        self.schedule = Schedule(timing, horizon)
        self.steps = int(round(horizon * 1e9 / self.schedule.period_ns))
        self.frame = wrench_frame or runtime.model.end_effector_link
        self.names = list(runtime.model.joint_names)
        self.input_hook, self.clock_ns = input_hook, clock_ns
        self.log = _Recorder(self.steps, len(runtime.ctrl.theta_hat))
        self._to_ctrl, self._to_plant = _Channel(), _Channel()
        self._events = sorted(events, key=lambda e: e.t)
        self.tau_plant: np.ndarray | None = None  # the command the plant holds
        self._timeout_ns = _ns(command_timeout) if math.isfinite(command_timeout) else None
        self._t_cmd = 0  # when the plant received tau_plant, ns
        self.command_timeouts = 0  # times the plant's watchdog zeroed the effort
        self.meas = plant.measure()
        self.k = 0
        self.outputs: list = []  # the runtime's outputs of the last step
        self._delays: list[float] = []

    @property
    def t(self) -> float:
        """Plant time of the next step, s."""
        return self.k * self.schedule.period_ns * 1e-9

    def step(self) -> Any:
        """
        One plant period: publish, controller ticks, plant update.

        Returns the measurement the plant published at the start of it.
        """
        sched, P, k = self.schedule, self.schedule.period_ns, self.k
        t_k = k * P
        while self._events and self._events[0].t * 1e9 <= t_k:
            self._events.pop(0).action(self.runtime, self.plant)
        meas, running = self.meas, not sched.plant_stalled(t_k)  # the stalls are drawn ahead
        if running:
            self._to_ctrl.send(sched.state_arrival(t_k), (t_k, meas))
        self.outputs = [self._tick(t) for t in sched.ticks_until(t_k, self._to_ctrl)]
        if running:
            cmd = self._to_plant.newest(t_k)
            if cmd is not None:
                self.tau_plant, self._t_cmd = cmd, t_k
        self._watchdog(t_k)  # the arm's own, also while its driver's process stalls
        if k < self.steps:
            self.log.record(k, t_k * 1e-9, meas, self.runtime, self.tau_plant)
        dt = P * 1e-9
        self.meas = (self.plant.hold(dt) if self.tau_plant is None
                     else self.plant.step(self.tau_plant, dt))
        self.k += 1
        return meas

    def _watchdog(self, t_k: int) -> None:
        """Zero the held command, or brake, once it is older than ``command_timeout``."""
        limit, tau = self._timeout_ns, self.tau_plant
        if limit is not None and tau is not None and t_k - self._t_cmd > limit and tau.any():
            self.tau_plant = None if self._brake else np.zeros_like(tau)  # None: the brakes
            self.command_timeouts += 1

    def _tick(self, t_tick: int) -> Any:
        got = self._to_ctrl.newest(t_tick)
        if got is not None:
            _deliver(self.runtime, self.names, self.frame, got, self.input_hook)
        clock = self.clock_ns
        t_wall = clock() if clock is not None else 0
        out = self.runtime.tick(t_tick * 1e-9)
        if clock is not None:
            self.log.tick_ns.append(clock() - t_wall)
        self.log.note_tick(out)
        if out.tau is not None:
            self._to_plant.send(self.schedule.command_arrival(t_tick), out.tau)
            self._delays.append((t_tick - _ns(self.runtime.state_stamp)) * 1e-9)
        return out

    def run(self) -> LoopLog:
        """Step to the end of the horizon and return the log."""
        while self.k < self.steps:
            self.step()
        return self.log.result(self._delays)


def run_loop(runtime: ControllerRuntime, plant: Plant, duration: float,
             timing: TimingModel = TimingModel(), events: Sequence[Event] = (),
             **kwargs: Any) -> LoopLog:
    """Run ``duration`` seconds of plant time and return the log (see :class:`LoopEngine`)."""
    return LoopEngine(runtime, plant, duration, timing, events, **kwargs).run()


_MODE_NAMES = {**{m: m.value for m in Mode}, **{m.value: m.value for m in Mode}}


def _ns(t: float) -> int:
    return int(round(t * 1e9)) if math.isfinite(t) else 0


def _deliver(runtime: ControllerRuntime, names: list[str], frame: str, got: tuple,
             hook: Callable | None) -> None:
    """Pass the joint state and wrench of one plant stamp to the runtime, as the node would."""
    t_ns, meas = got
    t = t_ns * 1e-9
    msg = (meas.q, meas.qdot, sensor_wrench_from_f_W(meas.R_W_ee, meas.f_W))
    if hook is not None:
        msg = hook(t, msg)
        if msg is None:
            return
    q, qdot, F_S = msg
    try:  # a refused message is dropped and counted by the runtime, as the node's guard does
        runtime.on_joint_state(names, q, qdot, t)
    except ValueError:
        pass
    try:
        runtime.on_wrench(frame, F_S, t)
    except ValueError:
        pass


class _Recorder:
    """Preallocated arrays of one run."""

    def __init__(self, steps: int, p: int) -> None:
        self.t = np.zeros(steps)
        self.x, self.x_d, self.f, self.f_true, self.f_d = (np.zeros((steps, 3)) for _ in range(5))
        self.theta = np.zeros((steps, p))
        self.k_hat = np.full(steps, np.nan)
        self.n_hat = np.zeros((steps, 3))
        self.tau: list[np.ndarray] = []
        self.mode: list[str] = []
        self.commands = self.ticks = 0
        self.tick_ns: list[int] = []
        self._out = None

    def note_tick(self, out) -> None:
        self.ticks += 1
        self.commands += out.tau is not None
        self._out = out

    def record(self, k: int, t: float, meas, runtime: ControllerRuntime, tau) -> None:
        out = self._out
        self.t[k], self.x[k], self.f[k], self.f_true[k] = t, meas.p_W, meas.f_W, meas.f_true_W
        self.x_d[k] = runtime.desired_position(t) if out is not None else meas.p_W
        self.f_d[k] = runtime.f_d_W
        self.theta[k] = runtime.theta_hat
        self.k_hat[k] = math.nan if out is None else out.k_hat
        if out is not None and out.n_W is not None:
            self.n_hat[k] = out.n_W
        self.tau.append(np.zeros_like(meas.q) if tau is None else tau)
        self.mode.append('none' if out is None else _MODE_NAMES[out.mode])

    def result(self, delays: list[float]) -> LoopLog:
        return LoopLog(self.t, self.x, self.x_d, self.f, self.f_true, self.f_d, self.theta,
                       np.array(self.tau), self.mode, self.commands, self.ticks,
                       np.array(delays), np.array(self.tick_ns), self.k_hat, self.n_hat)
