"""
The real-time path: the control thread decodes an input, ticks and publishes the effort.

:class:`ControlLoop` owns a thread of its own with a node and an executor of its own (the
node ``<controller>_rt``, hidden: ``ros2 node list`` shows only the controller). On that
thread run only the 1 kHz inputs (``joint_states``, the wrench) and, by ``tick_mode``, the
tick timer or the watchdog; for each new joint state it does exactly: decode the CDR
bytes, :meth:`ControllerRuntime.tick`, publish the effort. Everything else (parameter
services and validation, diagnostics, telemetry, logging, lifecycle) runs on the
controller node's thread, and meets this one only through three lock-free hand-overs:

* to the loop: :meth:`submit` (a validated parameter set, installed at the next tick
  boundary), :meth:`restart`, :meth:`hold_reference`, :meth:`follow_path` (a path planned
  on the node's thread) (``deque(maxlen=1)``: the newest wins);
* from the loop: :attr:`telemetry` (every ``telemetry_every``-th tick's output, which the
  node publishes every 10 ms), :attr:`latest` (the last commanding tick's output, for the
  path's progress and the markers), :attr:`events` (mode changes and
  callback errors, logged by the node), :attr:`errors` (callback errors by kind) and
  :attr:`holds` (how long each callback held the thread,
  :class:`~hybrid_force_controller.core.runtime.loop_stats.HoldStats`), and :attr:`recorder`,
  the flight recorder (core/runtime/flight_recorder.py; None when off): every tick writes a
  row of its preallocated ring (about 2 us, no array made) and a trigger (safe mode, a force
  above ``max_force``, contact lost in the force loop, a stall) appends a request to its
  ``requests`` deque; the node takes the snapshot and writes it off this thread.

This is the split realtime_tools and ros2_control make (parameters reach ``update()``
through a real-time buffer; the update loop never publishes through a plain publisher
from another thread). The thread asks for ``SCHED_FIFO`` at ``thread_priority`` (as
controller_manager does, 50 by default) and for ``cpu_affinity``; the executable's
``main`` puts the middleware's threads (which deliver its input) just below, and the node's
thread below those (:func:`~..common.scheduling.schedule_process`).
A refusal is reported, and the loop runs on.
"""
from __future__ import annotations

from collections import deque
import math
import sys
import threading
import time
from typing import Any, Callable, Sequence

from geometry_msgs.msg import WrenchStamped
import rclpy
from rclpy.context import Context
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future
from sensor_msgs.msg import JointState

from .telemetry import EffortOutput
from ..common.cdr import read_joint_state, read_wrench_stamped
from ..common.loop_timing import DelayStats, RateMeter
from ..common.paced_timer import create_paced_timer
from ..common.runner import make_executor
from ..common.scheduling import name_this_thread, set_thread_scheduling
from ...core.runtime.controller_runtime import ControllerRuntime, InputError
from ...core.runtime.flight_recorder import FlightRecorder
from ...core.runtime.loop_stats import hold_phases, HoldStats, LoopStats

__all__ = ['ControlLoop', 'LoopSettings']

CALLBACK_KINDS = ('joint_states', 'wrench', 'timer')  # what runs on the control thread
WATCHDOG_PERIODS = 5  # tick_mode joint_state: the watchdog checks every 5 periods
SPIN_SLICE_S = 0.1
# The GIL: a thread that wants it waits at most this long for the holder to let it go (the
# default 5 ms would let the node's thread hold the control thread for 5 ms)
GIL_SWITCH_S = 0.0002
FLIGHT_S = 2.0  # the flight recorder keeps this long of ticks at rate_hz


class LoopSettings:
    """What the control thread needs to know, fixed at configure."""

    def __init__(self, topics: dict[str, str], qos_in: Any, period: float, tick_mode: str,
                 executor: str, use_sim_time: bool, thread_priority: int,
                 cpu_affinity: Sequence[int], flight_recorder: bool = False,
                 flight_max_force: float = math.inf, link_domain: int | None = None) -> None:
        self.topics, self.qos_in, self.period = topics, qos_in, period
        self.tick_mode, self.executor, self.use_sim_time = tick_mode, executor, use_sim_time
        self.thread_priority, self.cpu_affinity = thread_priority, tuple(cpu_affinity)
        # the flight recorder: on or off, and the force (N) that triggers it (inf: none)
        self.flight_recorder, self.flight_max_force = flight_recorder, flight_max_force
        # the domain of the 1 kHz link when it is not the node's (HFC_CELL_DOMAIN_ID=robot)
        self.link_domain = link_domain


class ControlLoop:
    """The control thread of one controller (module docstring)."""

    def __init__(self, owner: Node, runtime: ControllerRuntime, settings: LoopSettings) -> None:
        self.runtime, self.settings = runtime, settings
        self.active = False
        # (TickOutput, stamp ns), for the node: the newest 0.5 s at 100 Hz (a node thread held
        # off for longer publishes only those, in one short burst)
        self.telemetry: deque = deque(maxlen=50)
        self.telemetry_every = 0  # every k-th commanding tick goes to telemetry (0: none)
        self.events: deque = deque(maxlen=256)  # ('mode'|'error'|'warning', ...), for the node
        self.errors = dict.fromkeys(CALLBACK_KINDS, 0)
        self.holds = HoldStats(CALLBACK_KINDS)
        # perf_counter at the end of a joint-state callback's inputs and of its tick
        self._marks = [0.0, 0.0]
        self._k_tick = 0
        self.delay, self.commands = DelayStats(4096), RateMeter()
        self.timing = LoopStats(4096)  # tick periods and compute times
        self.scheduling: list[str] | None = None  # warnings of the thread's set-up, once run
        self.native_id: int | None = None  # the thread's id, once it runs
        self._pending: deque = deque(maxlen=1)
        self._restart: deque = deque(maxlen=1)
        self._reference: deque = deque(maxlen=1)
        self._tare: deque = deque(maxlen=1)
        self._path: deque = deque(maxlen=1)
        self._moment: deque = deque(maxlen=1)
        self.latest: tuple | None = None  # (TickOutput, stamp ns) of the last commanding tick
        self._mode = None
        self._t_state, self._t_tick = 0.0, -1.0
        self._own_context = None if settings.link_domain is None else Context()
        if self._own_context is not None:  # the link's participant, on the robot's domain
            rclpy.init(context=self._own_context, domain_id=settings.link_domain,
                       signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node(f'_{owner.get_name()}_rt', namespace=owner.get_namespace(),
                         context=self._own_context or owner.context, use_global_arguments=False,
                         start_parameter_services=False, enable_rosout=False,
                         parameter_overrides=[Parameter('use_sim_time',
                                                        value=settings.use_sim_time)])
        self._clock = self.node.get_clock()
        # the loop clock's time, ns: /clock with sim time, else the wall clock (ROS time)
        self._now_ns = ((lambda: self._clock.now().nanoseconds) if settings.use_sim_time
                        else time.time_ns)
        self.effort = EffortOutput(self.node, settings.topics['commands'], runtime.model.n)
        self.recorder = self._make_recorder()
        self._make_endpoints()
        self._stop = Future()
        sys.setswitchinterval(GIL_SWITCH_S)
        self._thread = threading.Thread(target=self._run, name='control', daemon=True)
        self._thread.start()

    @property
    def _max_force(self) -> float:
        """Return the force that triggers the flight recorder, N (inf: none; 0 means none)."""
        return self.settings.flight_max_force or math.inf

    def _make_recorder(self) -> FlightRecorder | None:
        """Return the flight recorder of FLIGHT_S at the rate (None when it is off)."""
        s, rt = self.settings, self.runtime
        if not s.flight_recorder:
            return None
        return FlightRecorder(rt.model.n, rt.theta_hat.size, max(2, round(FLIGHT_S / s.period)),
                              self._max_force, rt.params.runtime.state_timeout)

    def _make_endpoints(self) -> None:
        s, node = self.settings, self.node
        node.create_subscription(JointState, s.topics['joint_states'],
                                 self._timed('joint_states', self._on_joint_state), s.qos_in,
                                 raw=True)
        node.create_subscription(WrenchStamped, s.topics['wrench'],
                                 self._timed('wrench', self._on_wrench), s.qos_in, raw=True)
        if s.tick_mode == 'timer':
            create_paced_timer(node, s.period, self._timed('timer', self._on_timer))
        else:
            create_paced_timer(node, WATCHDOG_PERIODS * s.period,
                               self._timed('timer', self._on_watchdog))

    # ------------------------------------------------------------------ the node's side
    def submit(self, params: Any) -> None:
        """Install a validated parameter set at the next tick boundary."""
        self._pending.append(params)

    def restart(self) -> None:
        """Start again from the arm's state at the next tick (a re-activation)."""
        self._restart.append(True)

    def start_tare(self, tare: Any) -> None:
        """Begin a tare (core/runtime/tare.py) at the next joint state; the node polls it."""
        self._tare.append(tare)

    def hold_reference(self, x_d_W: Sequence[float]) -> None:
        """Hold a user reference point from the next tick on."""
        self._reference.append(tuple(x_d_W))

    def set_moment_target(self, m_d_W: Sequence[float]) -> None:
        """Regulate the tilt moments to ``m_d_W`` (N m, base frame) from the next tick on."""
        self._moment.append(tuple(m_d_W))

    def follow_path(self, plan: Any, seq: int) -> None:
        """Follow a planned path (None: stop and hold) from the next tick on."""
        self._path.append((plan, seq))

    def stop(self, timeout: float = 5.0) -> None:
        """Stop the thread and destroy the loop's node (lifecycle cleanup, shutdown)."""
        self.active = False
        if not self._stop.done():
            self._stop.set_result(True)
        self._thread.join(timeout)
        self.node.destroy_node()
        if self._own_context is not None:
            self._own_context.try_shutdown()

    # ------------------------------------------------------------------ the thread
    def _run(self) -> None:
        self.native_id = threading.get_native_id()
        name_this_thread('hfc_control')  # per-thread CPU and profiles name it
        self.scheduling = set_thread_scheduling(self.settings.thread_priority,
                                                self.settings.cpu_affinity)
        executor = make_executor(self.settings.executor, self.node.context)
        try:
            executor.add_node(self.node)
            while not self._stop.done() and self.node.context.ok():
                executor.spin_until_future_complete(self._stop, timeout_sec=SPIN_SLICE_S)
        except Exception as exc:  # noqa: BLE001 - the context ended under the executor
            self.events.append(('error', f'control thread ended: {exc!r}'))
        finally:
            executor.shutdown(timeout_sec=1.0)

    def _timed(self, kind: str, callback: Callable) -> Callable:
        """Guard a callback (errors become events) and record how long it held the thread."""
        holds, events, clock = self.holds, self.events, time.perf_counter
        errors, marks, recorder = self.errors, self._marks, self.recorder

        def run(*args: Any) -> None:
            t0 = marks[0] = marks[1] = clock()
            try:
                callback(*args)
            except InputError as exc:
                errors[kind] += 1
                events.append(('warning', f'{kind}: {exc}'))
            except Exception as exc:  # noqa: BLE001 - an escaping exception ends the thread
                errors[kind] += 1
                events.append(('error', f'{kind} failed: {exc!r}'))
            t1 = clock()
            holds.record(kind, t1 - t0)
            if recorder is not None:  # the hold of the tick it recorded, if this one ticked
                recorder.note_hold(t1 - t0)
            if t1 - t0 > holds.longest[0]:  # where it went: HoldStats.where
                holds.longest = (t1 - t0, kind, hold_phases(kind, t0, marks, t1))
        return run

    def _now(self) -> float:
        return self._now_ns() * 1e-9

    def _apply_handovers(self) -> None:
        """Install what the node handed over since the last tick (the tick boundary)."""
        if self._pending:
            self.runtime.set_params(self._pending.popleft())
            if self.recorder is not None:
                self.recorder.configure(self._max_force, self.runtime.params.runtime.state_timeout)
        if self._restart:
            self._restart.popleft()
            self.runtime.restart()
            if self.recorder is not None:  # the time inactive is no stall
                self.recorder.forget_last()
        if self._reference:
            self.runtime.on_reference(self._reference.popleft())
        if self._tare:
            self.runtime.start_tare(self._tare.popleft())
        if self._path:
            self.runtime.on_path(*self._path.popleft())
        if self._moment:
            self.runtime.on_moment_target(self._moment.popleft())

    def _on_joint_state(self, raw: bytes) -> None:
        """
        Decode, hand the state to the runtime with its reception time, tick if it is new.

        The runtime checks the stamp against the loop clock at reception and maps it onto
        that clock (sender_clock.py); the tick goes by the mapped stamp.
        """
        msg = read_joint_state(raw)
        t_recv = self._now()
        t = msg.stamp_s if msg.stamp_s > 0.0 else t_recv  # unstamped: reception time
        self._apply_handovers()
        self.runtime.on_joint_state(msg.names, msg.position, msg.velocity, t, t_recv)
        self._marks[0] = self._marks[1] = time.perf_counter()
        t = self.runtime.state_stamp
        new, self._t_state = t > self._t_state, t
        if new and self.active and self.settings.tick_mode != 'timer':
            self._tick(t)

    def _on_wrench(self, raw: bytes) -> None:
        msg = read_wrench_stamped(raw)
        t_recv = self._now()
        t = msg.stamp_s if msg.stamp_s > 0.0 else t_recv
        self.runtime.on_wrench(msg.frame_id, msg.force, t, t_recv, msg.torque)

    def _on_timer(self) -> None:
        if self.active:
            self._apply_handovers()
            self._tick()

    def _on_watchdog(self) -> None:
        """
        Tick anyway after 2 periods without a tick, or when the clock jumped back.

        tick_mode joint_state: a stale input or a restarted clock (whose joint states the
        runtime refuses as older until a tick restarts it) still reaches the runtime.
        """
        since = self._now() - self._t_tick
        if self.active and (since >= 2.0 * self.settings.period
                            or since < -self.settings.period):
            self._apply_handovers()
            self._tick()

    def _tick(self, t_input: float = 0.0) -> None:
        """
        Run one tick at the loop clock's time and publish its effort.

        Never before ``t_input``, the stamp of the joint state that triggered it (with sim
        time the /clock update may arrive after the state).
        """
        t_start = time.perf_counter()
        now_ns = max(self._now_ns(), round(t_input * 1e9))
        self._t_tick = now_ns * 1e-9
        rt = self.runtime
        out = rt.tick(self._t_tick)
        if self.recorder is not None:
            self.recorder.record(self._t_tick, rt.joint_sample, rt.wrench_stamp, out)
        self._marks[1] = time.perf_counter()
        if out.tau is not None:
            self.effort.publish(out.tau)
            self.delay.record(self._t_tick + (time.perf_counter() - t_start) - self._t_state)
            self.commands.count += 1
            self.latest = (out, now_ns)
            self._k_tick += 1
            if self.telemetry_every and self._k_tick % self.telemetry_every == 0:
                self.telemetry.append((out, now_ns))
        if out.mode is not self._mode:
            self._mode = out.mode
            self.events.append(('mode', out.mode, out.status))
        self.timing.record(t_start, time.perf_counter())
