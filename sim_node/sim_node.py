"""
``sim`` node: the simulated arm against the elastic surface, as a ros2_control-like robot.

Publishes ``joint_states``, ``force_torque_sensor_broadcaster/wrench`` (force the
environment exerts on the tool, in ``tool0``, with noise; published just before the joint
state of the same step), ``sim/contact_wrench`` (true force the tool exerts on the
surface, base frame; at ``telemetry_rate_hz``), ``sim/contact_normal`` (the true surface
normal, into it, nearest the tool, base frame; beside it, while there is a surface),
``sim/tool_axis`` (physics:=mujoco: the tool's axis, the end effector's z, base frame; beside
it; the true moment about the tool's centre is ``sim/contact_wrench``'s torque),
``sim/link_masses`` (the true link masses,
once, transient local), ``robot_description`` (its URDF, transient local, like
robot_state_publisher) and ``/diagnostics`` (1 Hz: commands/s received, steps,
late callbacks, lost periods, the plant's mean time per step); takes efforts from
``effort_controller/commands``. Names are relative, so ``-r __ns:=/arm1`` moves them all.
Until the first valid command the arm is held still (brakes). ``joint_state_clock_offset`` and
``wrench_clock_offset`` (s) are added to the sensors' stamps: drivers on PCs whose clocks are
off (the true force and ``/clock`` keep the sim's time).

Real time: physics runs on wall time. At ``rate_hz`` (run_node's spin loop, which wakes at
each period's end: :meth:`SimNode.take_pacing`; a timer when the node is spun elsewhere) it
integrates every period that has passed since the last call (a late callback catches up, at most
``max_catch_up`` periods; older time is dropped and counted) with the last command held,
as a ros2_control effort controller holds it, and the watchdog's action for the periods that
ended more than ``command_timeout`` after it (``watchdog_action``: ``zero`` effort, the arm
falls; or ``brake``, it stops and holds, as a Franka's reflex or a UR's protective stop, until
the next valid command); then it publishes the newest state once. A command first lets the
periods that ended before it run on the old one. So the watchdog acts when the controller
stops even if this node was held meanwhile (a publish can block on a stopped reader's
shared-memory port in Fast DDS, or the whole machine can stall).
Lockstep (``lockstep:=true``, the deterministic reproduction mode) owns the time: it
publishes the state and ``/clock`` (equal stamps) and steps once per received command; a
wall watchdog steps anyway (held or zero effort, brakes before the first command), so a lost
message cannot deadlock the loop and a controller with ``use_sim_time`` gets its first tick:
0.2 s before the first command, ``lockstep_watchdog`` (2 s) after it, so that a machine too
busy to answer within 0.2 s slows the run down instead of changing it (a step on no command).
The surface (``stiffness``, ``surface_point``, ``surface_normal``, ``surface_enabled``,
``surface_shape``: a plane, cylinder or sphere, sim_surface.py) can be set at run time; a set
is validated as a whole and swapped in between two steps.

Physics (``physics``, read at start-up): ``paper`` (default) integrates the paper's model
(pinocchio ABA, frictionless spring: core/offline/simulator.py); ``mujoco`` steps MuJoCo compiled
from the same URDF with a sphere tool, a plane with damping and friction and a wrist force/torque
sensor (its reading, with the tool's weight, is the published wrench, torque included;
mujoco_plant.py). Both run on the same timers, watchdog and catch-up.
"""
from __future__ import annotations

import math
import sys
import time
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Vector3Stamped, WrenchStamped
from hybrid_force_controller.core.config.params import MODEL_SCHEMA, ParameterValidationError
from hybrid_force_controller.core.model.linalg import all_finite
from hybrid_force_controller.core.model.robot_model import default_urdf_path, RobotModel
from hybrid_force_controller.core.offline.environment import sensor_wrench_from_f_W, Surface
from hybrid_force_controller.core.offline.simulator import Measurement
from hybrid_force_controller.ros.common.cdr import RawMessage, read_float64_array
from hybrid_force_controller.ros.common.loop_timing import GapMeter, RateMeter
from hybrid_force_controller.ros.common.model_source import expand_description
from hybrid_force_controller.ros.common.node_params import check_choice, check_cpus
from hybrid_force_controller.ros.common.parameters import (check_values, declare_schema,
                                                           ParameterBinder)
from hybrid_force_controller.ros.common.qos import (CLOCK_QOS, COMMAND_QOS, DEFAULT_QOS,
                                                    DESCRIPTION_QOS, STATE_OUT_QOS)
from hybrid_force_controller.ros.common.runner import EXECUTORS, print_help, run_node, wants_help
from hybrid_force_controller.ros.common.scheduling import schedule_process
import numpy as np
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.time import Time
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, Header, String

from .plants import make_plant, touch_offset
from .sim_params import HELP_PARAMETERS, SIM_SCHEMA, SURFACE, UNIT, WATCHDOG_ACTIONS
from .sim_surface import surface_from_values

__all__ = ['SIM_SCHEMA', 'SimNode', 'held_periods', 'main']

WATCHDOG_S = 0.2  # lockstep, before the first command: the controller's first tick


def held_periods(t_begin: float, periods: int, dt: float, t_cmd: float, timeout: float) -> int:
    """
    Count the periods, of ``periods`` from ``t_begin``, that end within ``timeout`` of ``t_cmd``.

    Period k (1-based) ends at ``t_begin + k dt``; the plant holds the command for those, and
    applies zero effort for the rest (its watchdog).
    """
    span = (t_cmd + timeout - t_begin) / dt + 1e-9  # -inf before the first command
    return 0 if span <= 0.0 else min(periods, math.floor(span))  # math: 1 kHz, no numpy


class SimNode(Node):
    """The plant behind ROS topics (kwargs go to ``Node``)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('sim', **kwargs)
        v = declare_schema(self, SIM_SCHEMA, unit=UNIT)
        check_choice('executor', v['executor'], EXECUTORS)
        model_values = declare_schema(self, MODEL_SCHEMA)
        urdf = expand_description(model_values['robot_description']) or \
            default_urdf_path().read_text()
        model = RobotModel.from_parameters({**model_values, 'robot_description': urdf},
                                           v['joints'])
        self.joints = list(v['joints'])
        if sorted(self.joints) != sorted(model.joint_names):
            raise ParameterValidationError(f'joints must be a permutation of {model.joint_names}')
        self.to_model = [self.joints.index(j) for j in model.joint_names]
        self.to_msg = np.array([model.joint_names.index(j) for j in self.joints])
        # the message's order is the model's (the usual case): a slice copy, 0.1 us, not a take
        self.same_order = bool(np.array_equal(self.to_msg, np.arange(len(self.joints))))
        q0 = np.asarray(v['q0'], dtype=float)[self.to_model]
        kin0 = model.kinematics(q0, np.zeros(model.n))
        self.p0_W = kin0.p_W
        self.touch_offset = touch_offset(v, kin0.R_W_ee[:, 2])  # the tool's reach, 0 on paper
        surface, (self.sensor_frozen, self.sensor_offset) = self._surface(v)
        self.sim = make_plant(v, model, urdf, surface, q0, self.get_logger().info)
        if getattr(self.sim, 'impl_note', None):  # the paper's physics: compiled or Python
            self.get_logger().info(self.sim.impl_note)
        self.binder = ParameterBinder(self, [s for s in SIM_SCHEMA if s.name in SURFACE],
                                      self._surface, self._set_surface, unit=UNIT)
        self.dt, self.lockstep = 1.0 / v['rate_hz'], bool(v['lockstep'])
        self.command_timeout, self.max_catch_up = v['command_timeout'], v['max_catch_up']
        self.lockstep_watchdog = v['lockstep_watchdog']
        watchdog_spec = [s for s in SIM_SCHEMA if s.name == 'lockstep_watchdog']
        self.watchdog_binder = ParameterBinder(
            self, watchdog_spec, lambda v: check_values(watchdog_spec, v)['lockstep_watchdog'],
            self._set_lockstep_watchdog)
        check_choice('watchdog_action', v['watchdog_action'], WATCHDOG_ACTIONS)
        self.brake_on_timeout = v['watchdog_action'] == 'brake'
        # sensor clocks off by a constant (a driver on an unsynced PC), ns
        self.js_offset_ns = round(v['joint_state_clock_offset'] * 1e9)
        self.ft_offset_ns = round(v['wrench_clock_offset'] * 1e9)
        rate = v['telemetry_rate_hz']
        self.true_every = 0 if rate <= 0.0 else max(1, round(v['rate_hz'] / rate))
        self.base_frame, self.tool_frame = model.base_link, model.end_effector_link
        self.tau_cmd: np.ndarray | None = None
        self.tau_zero = np.zeros(model.n)  # the watchdog's effort (model order, as tau_cmd)
        self.t_cmd = self.t_pub = -np.inf
        self.counters = {'steps': 0, 'commands': 0, 'commands_rejected': 0,
                         'watchdog_steps': 0, 'late_callbacks': 0, 'lost_periods': 0,
                         'errors': 0, 'command_timeouts': 0}
        self.command_rate = RateMeter()
        self.command_gaps, self.state_gaps = GapMeter(), GapMeter()  # wall, per report
        self._timed_out = False
        self._physics_s, self._physics_steps0 = 0.0, 0  # time in the plant since the report
        self._make_messages()
        self._make_endpoints(urdf)
        self._publish_masses(v['masses'] or model.theta_nominal.tolist())
        self._t_wall = time.monotonic()
        self._publish(self.sim.measure())
        # lockstep runs as fast as it can: at FIFO it would starve the machine (and its reader)
        self._scheduling = (0 if self.lockstep else v['thread_priority'],
                            check_cpus(v['cpu_affinity']))

    def schedule_this_thread(self) -> None:
        """
        Give the calling thread, the one that spins this node, its real-time scheduling.

        SCHED_FIFO ``thread_priority`` (and ``cpu_affinity``) for it, one below for the
        middleware's threads (``ros/common/scheduling.py``). ``main`` calls it; a node
        built in another program leaves that program's threads alone.
        """
        priority, cpus = self._scheduling
        for warning in schedule_process(priority, 'sim thread', cpus=cpus):
            self.get_logger().warning(warning)

    def _make_messages(self) -> None:
        """
        Messages built once and refilled in place by every publish.

        The 1 kHz joint state and wrench are kept serialized (ros/common/cdr.py ``RawMessage``) and
        published as bytes: rclpy's conversion of every field cost more than the physics.
        """
        zeros = [0.0] * len(self.joints)
        self.js = RawMessage('joint_state', JointState(name=self.joints, position=zeros,
                                                       velocity=zeros, effort=zeros))
        self.ft = RawMessage('wrench_stamped', WrenchStamped(header=Header(
            frame_id=self.tool_frame)))
        self.true = WrenchStamped(header=Header(frame_id=self.base_frame))
        self.normal = Vector3Stamped(header=Header(frame_id=self.base_frame))
        self.axis = Vector3Stamped(header=Header(frame_id=self.base_frame))
        self.clock_msg = ClockMsg()
        self.n_pub = 0

    def _make_endpoints(self, urdf: str) -> None:
        self.pub_js = self.create_publisher(JointState, 'joint_states', STATE_OUT_QOS)
        self.pub_ft = self.create_publisher(WrenchStamped,
                                            'force_torque_sensor_broadcaster/wrench',
                                            STATE_OUT_QOS)
        self.pub_true = self.create_publisher(WrenchStamped, 'sim/contact_wrench', DEFAULT_QOS)
        self.pub_normal = self.create_publisher(Vector3Stamped, 'sim/contact_normal', DEFAULT_QOS)
        self.pub_axis = self.create_publisher(Vector3Stamped, 'sim/tool_axis', DEFAULT_QOS)
        self.pub_clock = (self.create_publisher(ClockMsg, '/clock', CLOCK_QOS)
                          if self.lockstep else None)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', DEFAULT_QOS)
        self.pub_description = self.create_publisher(String, 'robot_description',
                                                     DESCRIPTION_QOS)
        self.pub_description.publish(String(data=urdf))
        self.create_subscription(Float64MultiArray, 'effort_controller/commands',
                                 self._guarded('command', self._on_command), COMMAND_QOS,
                                 raw=True)  # read from the CDR bytes: cheaper at 1 kHz
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        period, tick = ((WATCHDOG_S / 4, self._on_watchdog) if self.lockstep
                        else (self.dt, self._advance))
        self.timer = self.create_timer(period, self._guarded('timer', tick), clock=steady)
        self.create_timer(1.0, self._guarded('diagnostics', self._on_diagnostics), clock=steady)

    def _publish_masses(self, masses: list[float]) -> None:
        """
        Publish the arm's true link masses on ``sim/link_masses`` once (transient local).

        What theta_hat converges to with the ``link_masses`` parameter set: the report draws
        them as the true values (Fig. 5).
        """
        self.pub_masses = self.create_publisher(Float64MultiArray, 'sim/link_masses',
                                                DESCRIPTION_QOS)
        self.pub_masses.publish(Float64MultiArray(data=[float(m) for m in masses]))

    def _surface(self, v: dict[str, Any]) -> tuple[Surface | None, tuple]:
        """Build the surface and the sensor's faults of ``v`` (sim_surface.py; SurfaceError)."""
        check = getattr(getattr(self, 'sim', None), 'check_surface', None)  # MuJoCo's limits
        return surface_from_values(v, self.p0_W, self.touch_offset, check)

    def _set_surface(self, values: tuple[Surface | None, tuple]) -> None:
        """Swap the surface in; the contact torque measure() cached for the old one is dropped."""
        self.sim.surface, (self.sensor_frozen, self.sensor_offset) = values
        self.sim._tau_c = None

    def _set_lockstep_watchdog(self, seconds: float) -> None:
        self.lockstep_watchdog = seconds

    def _guarded(self, name: str, callback: Callable) -> Callable:
        """Wrap a callback: exceptions are counted and logged (throttled), never raised."""
        def run(*args: Any) -> None:
            try:
                callback(*args)
            except Exception as exc:  # noqa: BLE001 - an escaping exception kills the node
                self.counters['errors'] += 1
                self.get_logger().error(f'{name} failed: {exc!r}', throttle_duration_sec=1.0)
        return run

    def _on_command(self, raw: bytes) -> None:
        tau = read_float64_array(raw)
        if tau.shape != (len(self.joints),) or not all_finite(tau):
            self.counters['commands_rejected'] += 1
            self.get_logger().warning(f'rejected command {tau.tolist()}: need {len(self.joints)}'
                                      ' finite efforts; keeping the last valid one',
                                      throttle_duration_sec=1.0)
            return
        t_cmd = self._time()  # before the catch-up, whose publish may block
        if not self.lockstep:  # the periods that ended before it came ran on the old one
            self._advance()
        self.counters['commands'] += 1
        self.command_rate.count += 1
        self.command_gaps.mark(time.monotonic())
        self.tau_cmd, self.t_cmd = tau[self.to_model], t_cmd
        self._timed_out = False
        if self.lockstep:
            self._step(self.tau_cmd)

    def _advance(self) -> None:
        """
        Real time (the timer's callback): integrate every period that ended since the last one.

        The command is held for the periods that ended within ``command_timeout`` of it, zero
        effort after (the watchdog per period, as on a robot that kept running while this
        callback waited, e.g. on a publish blocked in the middleware).
        """
        periods = int((time.monotonic() - self._t_wall) / self.dt)
        if periods <= 0:
            return
        if periods > 1:
            self.counters['late_callbacks'] += 1
        if periods > self.max_catch_up:
            self.counters['lost_periods'] += periods - self.max_catch_up
            self._t_wall += (periods - self.max_catch_up) * self.dt
            periods = self.max_catch_up
        t_begin = self._t_wall
        self._t_wall += periods * self.dt
        self._run(t_begin, periods)

    def take_pacing(self) -> Callable[[], float] | None:
        """
        Hand the real-time step to the caller's spin loop (run_node); None in lockstep.

        The 1 kHz timer is destroyed: with the EventsExecutor its expiry woke a timer thread
        that then woke this one, two hand-offs and 4 % of a core per period (docs/results.md
        section 39). The caller instead calls the returned function, which steps what is due
        (:meth:`_advance`, guarded) and returns the seconds until the next period ends, and
        spins the executor for at most that long (a command wakes it sooner). A node built in
        another program keeps its timer.
        """
        if self.lockstep:
            return None
        self.destroy_timer(self.timer)
        self.timer = None
        advance = self._guarded('timer', self._advance)

        def pace() -> float:
            advance()
            return max(0.0, self._t_wall + self.dt - time.monotonic())
        return pace

    def _on_watchdog(self) -> None:
        """Lockstep: a step after WATCHDOG_S (wall) without a command, lockstep_watchdog then."""
        limit = WATCHDOG_S if self.tau_cmd is None else self.lockstep_watchdog
        if time.monotonic() - self.t_pub >= limit:
            self.counters['watchdog_steps'] += 1
            self._run(self.sim.t, 1)

    def _time(self) -> float:
        """Seconds on the clock that command_timeout uses: sim time in lockstep, else wall."""
        return self.sim.t if self.lockstep else time.monotonic()

    def _run(self, t_begin: float, periods: int) -> None:
        """
        Step ``periods`` from ``t_begin`` (on :meth:`_time`'s clock), then publish.

        The watchdog (:func:`held_periods`): the command for the periods that end within
        ``command_timeout`` of it, zero effort or the brakes after (``watchdog_action``; one
        count and warning per timeout); brakes before the first command.
        """
        held = periods if self.tau_cmd is None else held_periods(
            t_begin, periods, self.dt, self.t_cmd, self.command_timeout)
        if held == periods:
            self._step(self.tau_cmd, periods)
            return
        if not self._timed_out:
            self._timed_out = True
            self.counters['command_timeouts'] += 1
            self.get_logger().warning('no valid command within command_timeout: ' + (
                'brakes on' if self.brake_on_timeout else 'zero effort'))
        if held:
            self._integrate(self.tau_cmd, held)
        self._step(None if self.brake_on_timeout else self.tau_zero, periods - held)

    def _step(self, tau: np.ndarray | None, periods: int = 1) -> None:
        """``periods`` steps of 1/rate_hz, then publish (``None``: brakes hold the arm)."""
        self._publish(self._integrate(tau, periods))

    def _integrate(self, tau: np.ndarray | None, periods: int) -> Measurement:
        t0 = time.perf_counter()
        if tau is None:  # the brakes hold the arm still
            meas = self.sim.hold(periods * self.dt)
        else:
            for _ in range(periods):
                meas = self.sim.step(tau, self.dt)
        self._physics_s += time.perf_counter() - t0
        self.counters['steps'] += periods
        return meas

    def _publish(self, meas: Measurement) -> None:
        """
        Publish the newest state: the wrench first, then the joint state.

        So a controller that ticks on the joint state has the wrench of the same step.
        """
        t_ns = round(meas.t * 1e9) if self.lockstep else time.time_ns()  # ROS time: wall
        js, ft, true = self.js, self.ft, self.true
        q, qdot, tau = js.arrays
        for src, dst in ((meas.q, q), (meas.qdot, qdot), (meas.tau, tau)):
            if self.same_order:  # into the message's bytes, no copy between
                dst[:] = src
            else:
                np.take(src, self.to_msg, out=dst)
        if not self.sensor_frozen:  # frozen: the reused message repeats its last reading
            ft.arrays[0][:] = sensor_wrench_from_f_W(meas.R_W_ee, meas.f_W)
            if self.sensor_offset is not None:  # a biased sensor
                ft.arrays[0][:] += self.sensor_offset
            torque = getattr(self.sim, 'torque_S', None)  # MuJoCo's wrist torque sensor
            if torque is not None:
                ft.arrays[1][:] = torque
        js.set_stamp(t_ns + self.js_offset_ns)
        ft.set_stamp(t_ns + self.ft_offset_ns)
        self.pub_ft.publish(ft.serialized())
        self.pub_js.publish(js.serialized())
        stamp = None
        if self.true_every and self.n_pub % self.true_every == 0:
            stamp = Time(nanoseconds=t_ns).to_msg()
            force, torque = true.wrench.force, true.wrench.torque
            force.x, force.y, force.z = (float(c) for c in meas.f_true_W)
            T_S = getattr(self.sim, 'torque_S', None)  # tool on part: -R T_S (no weight torque)
            if T_S is not None:
                torque.x, torque.y, torque.z = (float(c) for c in -meas.R_W_ee.dot(T_S))
            true.header.stamp = stamp
            self.pub_true.publish(true)
            self._publish_normal(meas.p_W, meas.R_W_ee, stamp)
        self.n_pub += 1
        self.state_gaps.mark(time.monotonic())
        if self.pub_clock is not None:
            self.clock_msg.clock = stamp or Time(nanoseconds=t_ns).to_msg()
            self.pub_clock.publish(self.clock_msg)
        self.t_pub = time.monotonic()

    def _publish_normal(self, p_W: np.ndarray, R_W_ee: np.ndarray, stamp: Any) -> None:
        """Publish the true surface normal nearest the tool, and MuJoCo's tool's axis beside it."""
        n_W = self.sim.contact_normal(p_W)
        if n_W is not None:
            has_axis = getattr(self.sim, 'torque_S', None) is not None  # the paper's: a point
            for msg, pub, vec in ((self.normal, self.pub_normal, n_W),
                                  (self.axis, self.pub_axis, R_W_ee[:, 2]))[:1 + has_axis]:
                msg.vector.x, msg.vector.y, msg.vector.z = (float(c) for c in vec)
                msg.header.stamp = stamp
                pub.publish(msg)

    def _on_diagnostics(self) -> None:
        stamp = (Time(nanoseconds=round(self.sim.t * 1e9)) if self.lockstep
                 else self.get_clock().now()).to_msg()
        steps = self.counters['steps'] - self._physics_steps0
        physics_us = 1e6 * self._physics_s / steps if steps else float('nan')
        self._physics_s, self._physics_steps0 = 0.0, self.counters['steps']
        values = {**self.counters,
                  'commands_per_s': f'{self.command_rate.rate(time.monotonic()):.4g}',
                  'physics_step_mean_us': f'{physics_us:.4g}',
                  **{k: f'{v:.4g}' for k, v in self.command_gaps.take('command_gap').items()},
                  **{k: f'{v:.4g}' for k, v in self.state_gaps.take('state_gap').items()},
                  'sim_time_s': f'{self.sim.t:.4f}', 'lockstep': self.lockstep}
        status = DiagnosticStatus(
            level=DiagnosticStatus.OK, name=f'{self.get_fully_qualified_name()}: simulated arm',
            message='running', hardware_id=self.get_name(),
            values=[KeyValue(key=k, value=str(x)) for k, x in values.items()])
        self.pub_diag.publish(DiagnosticArray(header=Header(stamp=stamp), status=[status]))


def main(args: list[str] | None = None) -> int:
    """Run the simulator until SIGINT/SIGTERM (0); 1 if its parameters are invalid."""
    if wants_help(args):
        print_help('sim', "Simulated arm against an elastic surface (node 'sim'): efforts in, "
                   'joint_states + F/T wrench out.', HELP_PARAMETERS)
        return 0

    def make_node() -> SimNode:
        node = SimNode()
        node.schedule_this_thread()
        return node
    return run_node(make_node, 'sim', args, cell=True)


if __name__ == '__main__':
    sys.exit(main())
