"""
``hybrid_force_controller`` managed node: messages -> ControllerRuntime -> messages.

Lifecycle: *configure* loads the robot model (``robot_description`` parameter, a ``.xacro``
path, the ``robot_description`` topic, or the bundled arm with ``use_bundled_model``) and
the parameters, and subscribes the inputs; *activate* starts commanding (the runtime
restarts, so the reference blends from the arm's position and velocity: no effort jump);
*deactivate* stops commanding (the hardware keeps its own hold); *cleanup* drops the model.
``autostart`` (default true) configures and activates at start. Parameter services work
in every state: before configure only the model-free checks run, the rest at configure.

Threads: the 1 kHz path (inputs, tick, effort) runs on the control thread of
:class:`~.control_loop.ControlLoop`, at SCHED_FIFO ``thread_priority``; this node's own
thread does everything else (parameter services and validation, lifecycle, diagnostics,
telemetry, logging). A validated set reaches the loop at its next tick boundary.

Topics are relative, so ``-r __ns:=/arm1`` moves them all (``/diagnostics`` stays absolute):
subscribes ``joint_states``, ``force_torque_sensor_broadcaster/wrench``, ``~/reference``,
``~/path``; publishes ``effort_controller/commands`` every tick, ``~/x``, ``~/x_desired``,
``~/wrench``, ``~/wrench_desired``, ``~/error``, ``~/theta_hat`` at ``telemetry_rate_hz``,
and ``~/path_status``, ``~/path_progress``, ``~/markers`` (path_topics.py).
The names are resolved here (remappings included) and the control thread's node uses them
as they are. QoS: :mod:`.qos`. ``/diagnostics`` (1 Hz) adds the input-to-command delay
(joint-state stamp to effort published), the tick period, the commands/s and how long each
kind of callback held the control thread (``loop_hold_max_ms``, ``hold_*``). A flight recorder
keeps the loop's last 2 s and, on a fault, writes them to ``flight_recorder_dir``: 1.5 s before
the fault and 0.5 s after it (flight_dumps.py).
"""
from __future__ import annotations

from collections import Counter
import gc
import sys
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from std_msgs.msg import String

from .control_loop import ControlLoop, LoopSettings
from .diagnostics import clock_offset_warnings, controller_status, EVENT_COUNTERS, loop_report
from .flight_dumps import FlightDumps
from .path_topics import PathTopics
from .task_interface import TaskInterface
from .telemetry import ControllerOutputs, TOPIC_COMMANDS
from ..common.cell import cell_domains
from ..common.model_source import expand_description, missing_description_hint
from ..common.node_params import check_choice, check_cpus, CONTROLLER_NODE_SCHEMA, SENSOR_QOS
from ..common.node_params import TICK_MODES
from ..common.paced_timer import create_paced_timer
from ..common.parameters import check_values, declare_schema, ParameterBinder
from ..common.qos import DEFAULT_QOS, DESCRIPTION_QOS, sensor_in_qos
from ..common.runner import EXECUTORS, print_help, run_node, wants_help
from ..common.scheduling import schedule_process
from ...core.config.params import build_params, CONTROLLER_SCHEMA, MODEL_SCHEMA
from ...core.config.params import ParameterValidationError
from ...core.model.robot_model import RobotModel
from ...core.runtime.controller_runtime import ControllerRuntime, InputError, Mode
from ...core.runtime.steady_tick import kernels_cached

__all__ = ['ControllerNode', 'main']

TOPIC_JOINT_STATES = 'joint_states'
TOPIC_WRENCH = 'force_torque_sensor_broadcaster/wrench'
TOPIC_DESCRIPTION = 'robot_description'
_OK, _FAIL = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
HOUSEKEEPING_S = 0.1  # the node drains the loop's events (logs) this often
TELEMETRY_DRAIN_S = 0.01  # and publishes the telemetry the loop queued this often (wall)


class ControllerNode(LifecycleNode):
    """Thin adapter around :class:`~.runtime.ControllerRuntime` (kwargs go to the node)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('hybrid_force_controller', **kwargs)
        self.node_values = declare_schema(self, CONTROLLER_NODE_SCHEMA)
        self.model_values = declare_schema(self, MODEL_SCHEMA)
        declare_schema(self, CONTROLLER_SCHEMA, unit=('n',))
        nv = self.node_values
        check_choice('tick_mode', nv['tick_mode'], TICK_MODES)
        check_choice('executor', nv['executor'], EXECUTORS)
        check_choice('sensor_qos', nv['sensor_qos'], SENSOR_QOS)
        check_cpus(nv['cpu_affinity'])
        self.binder = ParameterBinder(self, CONTROLLER_SCHEMA, self._validate,
                                      self._install, unit=('n',))
        self.node_binder = ParameterBinder(
            self, [s for s in CONTROLLER_NODE_SCHEMA if s.name == 'telemetry_rate_hz'],
            lambda v: check_values(CONTROLLER_NODE_SCHEMA, v), self._install_node_values)
        self.errors: Counter[str] = Counter()
        self.state_label, self.last_error = 'unconfigured', ''
        self.runtime: ControllerRuntime | None = None
        self.params = None  # the accepted parameter set (the loop installs it at a tick)
        self.model: RobotModel | None = None
        self.loop: ControlLoop | None = None
        self.flight: FlightDumps | None = None  # the flight recorder's dumps (None: off)
        self._description_msg: str | None = None
        self.task: TaskInterface | None = None  # ~/reference, ~/target_wrench, ~/tare
        steady = Clock(clock_type=ClockType.STEADY_TIME)  # drains in lockstep too
        self.create_timer(TELEMETRY_DRAIN_S, self._guarded('telemetry', self._on_telemetry),
                          clock=steady)
        self._events: dict[str, int] = {}
        self._clock_warned: set[str] = set()  # input streams whose clock offset was logged
        self._scheduling_reported = False
        self._node_scheduling: list[str] = []
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', DEFAULT_QOS)
        create_paced_timer(self, nv['diagnostic_updater.period'],
                           self._guarded('diagnostics', self._on_diagnostics))
        create_paced_timer(self, HOUSEKEEPING_S, self._guarded('housekeeping', self._housekeeping))
        if self._description_param() == '' and not nv['use_bundled_model']:
            self.create_subscription(String, TOPIC_DESCRIPTION,
                                     self._guarded('robot_description', self._on_description),
                                     DESCRIPTION_QOS)
            self.get_logger().warning(missing_description_hint(self._topic(TOPIC_DESCRIPTION)))
        elif nv['autostart']:
            self._autostart(raise_errors=True)

    # ------------------------------------------------------------------ set-up
    def _topic(self, name: str) -> str:
        return self.resolve_topic_name(name)

    def _description_param(self) -> str:
        return str(self.get_parameter('robot_description').value)

    def _install_node_values(self, values: dict[str, Any]) -> None:
        self.node_values['telemetry_rate_hz'] = values['telemetry_rate_hz']
        if self.loop is not None:
            self.loop.telemetry_every = self._decimation()

    def _decimation(self) -> int:
        """Return k: telemetry every k-th tick (0: never)."""
        rate = self.runtime.params.runtime.rate_hz
        telemetry = self.node_values['telemetry_rate_hz']
        return 0 if telemetry <= 0.0 else max(1, round(rate / telemetry))

    def _autostart(self, raise_errors: bool) -> None:
        """Configure and activate; a configure failure raises (start-up) or is logged."""
        if self.trigger_configure() != _OK:
            if raise_errors:
                raise ParameterValidationError(self.last_error)
            return
        self.trigger_activate()

    def _on_description(self, msg: String) -> None:
        first = self._description_msg is None
        self._description_msg = msg.data
        self.get_logger().info(f'robot_description received ({len(msg.data)} characters)')
        if first and self.node_values['autostart'] and self.state_label == 'unconfigured':
            self._autostart(raise_errors=False)

    def _load_model(self) -> RobotModel:
        """Load the model from the parameter, the topic, or (when asked) the bundled arm."""
        param = self._description_param()
        values = dict(self.model_values)
        joints = list(self.get_parameter('joints').value)
        if param:
            values['robot_description'] = expand_description(param)
        elif self._description_msg is not None:
            values['robot_description'] = self._description_msg
        elif not self.node_values['use_bundled_model']:
            raise ParameterValidationError(missing_description_hint(
                self._topic(TOPIC_DESCRIPTION)))
        try:
            return RobotModel.from_parameters(values, joints)
        except ValueError as exc:
            if values['robot_description']:
                raise
            raise ParameterValidationError(
                f'{exc} (robot_description is empty and use_bundled_model is true, so the '
                "model is the bundled 2-link arm of the paper: give your robot's URDF)"
            ) from exc

    def _current_values(self) -> dict[str, Any]:
        return {s.name: self.get_parameter(s.name).value for s in CONTROLLER_SCHEMA}

    # ------------------------------------------------------------------ parameters
    def _validate(self, values: dict[str, Any]) -> Any:
        """Full validation once a model is loaded; the model-free checks before."""
        if self.runtime is None:
            return check_values(CONTROLLER_SCHEMA, values)
        return self.runtime.validate(values)

    def _install(self, validated: Any) -> None:
        """Hand an accepted set to the control thread (it takes effect at its next tick)."""
        if self.loop is not None and not isinstance(validated, dict):
            self.params = validated
            self.loop.submit(validated)

    # ------------------------------------------------------------------ lifecycle
    def _loop_settings(self) -> LoopSettings:
        nv = self.node_values
        topics = {'joint_states': self._topic(TOPIC_JOINT_STATES),
                  'wrench': self._topic(TOPIC_WRENCH), 'commands': self._topic(TOPIC_COMMANDS)}
        return LoopSettings(topics, sensor_in_qos(nv['sensor_qos'], nv['sensor_depth']),
                            1.0 / self.runtime.params.runtime.rate_hz, self._tick_mode(),
                            nv['executor'], bool(self.get_parameter('use_sim_time').value),
                            self._thread_priority(), nv['cpu_affinity'],
                            nv['flight_recorder_dir'] != '', nv['flight_recorder_max_force'],
                            cell_domains().link_domain)

    def _thread_priority(self) -> int:
        """Return ``thread_priority``, or 0 with sim time (a lockstep loop runs flat out)."""
        if self.get_parameter('use_sim_time').value:
            return 0
        return self.node_values['thread_priority']

    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.model = self._load_model()
            params = build_params(self.model, self._current_values())
            if params.law.tick_impl == 'compiled' and not kernels_cached():
                self.get_logger().info('compiling the tick (numba kernels, about 5-20 s, once: '
                                       'cached for the next starts)')
            self.runtime = ControllerRuntime(self.model, params)
        except ValueError as exc:
            self.model = self.runtime = None
            self.last_error = str(exc)
            self.get_logger().error(f'configure failed: {exc}')
            return _FAIL
        self.params = self.runtime.params
        self._ran = False  # a fresh runtime starts from the arm by itself
        self.outputs = ControllerOutputs(self, self.model.base_link, self.model.theta_names)
        self.task = TaskInterface(self)
        self.paths = PathTopics(self, self.model.base_link, self._guarded)
        # a full collection holds the GIL (300 ms seen): before the control thread runs
        gc.collect()
        gc.freeze()  # the start-up heap is never scanned again: shorter collector passes
        self.loop = ControlLoop(self, self.runtime, self._loop_settings())
        self.loop.telemetry_every = self._decimation()
        if self.loop.recorder is not None:
            self.flight = FlightDumps(self.node_values['flight_recorder_dir'], self.model,
                                      self.get_logger().warning)
        self.state_label = 'inactive'
        note = self.runtime.ctrl.tick_note  # a warning when numba is missing: the reference runs
        (self.get_logger().warning if 'not importable' in note else self.get_logger().info)(note)
        self.get_logger().info(f"configured: {self.model.n} joints, base '{self.model.base_link}'"
                               f", inputs {self.loop.settings.topics['joint_states']}, "
                               f"commands {self.loop.settings.topics['commands']}")
        return _OK

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._ran:  # re-activation: the next tick starts again from the arm's state
            self.loop.restart()
        self._ran = True
        self.loop.holds.reset()
        self.loop.active = True
        self.state_label = 'active'
        self.get_logger().info('active: commanding')
        return _OK

    def _tick_mode(self) -> str:
        """Return the tick mode in use (auto: joint_state, or timer with sim time)."""
        mode = self.node_values['tick_mode']
        if mode == 'auto':
            mode = 'timer' if self.get_parameter('use_sim_time').value else 'joint_state'
        return mode

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.loop.active = False
        self.state_label = 'inactive'
        self.get_logger().info('inactive: no commands (the hardware holds)')
        return _OK

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        recorder = None if self.loop is None else self.loop.recorder
        if self.loop is not None:
            self.loop.stop()
            self.loop = None
        if self.flight is not None:  # a pending dump starts, one being written finishes
            self.flight.join(recorder=recorder)
            self.flight = None
        if self.task is not None:
            self.task.destroy()
            self.task = None
        if self.runtime is not None:
            self.outputs.destroy()
            self.paths.destroy()
        self.runtime = self.model = self.params = None
        self.state_label = 'unconfigured'
        return _OK

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.state_label == 'active':
            self.on_deactivate(state)
        if self.state_label == 'inactive':
            self.on_cleanup(state)
        self.state_label = 'finalized'
        return _OK

    def schedule_this_thread(self) -> None:
        """
        Schedule the middleware's threads below the control thread, and the node's below them.

        See :func:`~..common.scheduling.schedule_process`; a node built in another program leaves
        that program's threads alone.
        """
        keep = () if self.loop is None or self.loop.native_id is None else (self.loop.native_id,)
        top = self._thread_priority()  # the control thread's; the middleware delivers its input
        self._node_scheduling = schedule_process(top - 2, 'node thread', keep, others=top - 1)

    def destroy_node(self) -> None:
        """Stop the control thread first (a node destroyed without a shutdown transition)."""
        recorder = None if self.loop is None else self.loop.recorder
        if self.loop is not None:
            self.loop.stop()
            self.loop = None
        if self.flight is not None:  # a pending dump starts, one being written finishes
            self.flight.join(recorder=recorder)
        super().destroy_node()

    # ------------------------------------------------------------------ callbacks
    def _guarded(self, name: str, callback: Callable) -> Callable:
        """Wrap a callback: exceptions are counted and logged (throttled), never raised."""
        def run(*args: Any) -> None:
            try:
                callback(*args)
            except InputError as exc:
                self.errors[name] += 1
                self.get_logger().warning(f'{name}: {exc}', throttle_duration_sec=1.0)
            except Exception as exc:  # noqa: BLE001 - an escaping exception kills the node
                self.errors[name] += 1
                self.get_logger().error(f'{name} failed: {exc!r}', throttle_duration_sec=1.0)
        return run

    def _on_telemetry(self) -> None:
        """Publish what the control thread queued (every k-th tick's output)."""
        queue = self.loop.telemetry if self.loop is not None else ()
        while queue:
            self.outputs.publish_telemetry(*queue.popleft())

    def _housekeeping(self) -> None:
        """Log what the control thread reported: its scheduling, mode changes, errors."""
        loop = self.loop
        if loop is None:
            return
        if loop.scheduling is not None and not self._scheduling_reported:
            self._scheduling_reported = True  # one warning: the loop's, else the node's
            for warning in (loop.scheduling or self._node_scheduling)[:1]:
                self.get_logger().warning(warning)
        while loop.events:
            self._log_event(loop.events.popleft())
        if self.flight is not None and loop.recorder is not None:
            self.flight.poll(loop.recorder)  # logs 'flight recorder: why at t=...: path'

    def _log_event(self, event: tuple) -> None:
        kind, *rest = event
        if kind == 'mode':  # one call site per severity: rclpy refuses to mix them
            mode, status = rest
            if mode in (Mode.SAFE, Mode.NO_SURFACE):
                self.get_logger().error(f'mode {mode.value}: {status}')
            else:
                self.get_logger().info(f'mode {mode.value}: {status}')
            return
        if kind == 'warning':  # counted by the loop (loop.errors)
            self.get_logger().warning(rest[0], throttle_duration_sec=1.0)
        else:
            self.get_logger().error(rest[0], throttle_duration_sec=1.0)

    def _on_diagnostics(self) -> None:
        self._housekeeping()
        loop = self.loop
        extra: dict[str, Any] = {'lifecycle_state': self.state_label}
        timing: dict[str, float] = {}
        new_events: dict[str, int] = {}
        if loop is not None:
            timing = loop_report(loop, extra)
        if self.runtime is not None:
            counts = {k: self.runtime.counters[k] for k in EVENT_COUNTERS}
            new_events = {k: v - self._events.get(k, 0) for k, v in counts.items()}
            self._events = counts
            for warning in clock_offset_warnings(self.runtime.clock_offsets(), self._clock_warned):
                self.get_logger().warning(warning)
            extra['delay_margin_ms'] = self.runtime.delay_margin(self.params) * 1e3
            extra.update(self.task.report() if self.task is not None else {})
        if self.last_error and self.runtime is None:
            extra['configure_error'] = self.last_error
        errors = dict(self.errors)
        if loop is not None:
            errors.update({k: v for k, v in loop.errors.items() if v})
        self.pub_diag.publish(controller_status(
            self.get_clock().now().to_msg(), self.get_name(), self.runtime, new_events,
            timing, errors, extra, self.get_fully_qualified_name()))


HELP_PARAMETERS = (
    ('robot_description', "URDF XML, .urdf or .xacro path ('': robot_description topic)"),
    ('use_bundled_model', "true: the paper's 2-link arm when robot_description is ''"),
    ('joints', 'controlled joints, in the order of the effort command'),
    ('f_d, n', 'desired normal force (N) and contact normal (base frame)'),
    ('f_d_rate', 'a new f_d (or ~/target_wrench) is ramped at this rate, N/s (0: a step)'),
    ('path_speed, path_max_*', '~/path: speed of an untimed path, its limits (README)'),
    ('wrench_offset, tare_time', "the sensor's bias (~/tare sets it), the tare's averaging"),
    ('lambda1, lambda2, gamma', 'gains of eqs. (11) and (26)'),
    ('rate_hz', 'control rate (default 1000)'),
    ('telemetry_rate_hz', 'rate of ~/x ... ~/theta_hat (default 100)'),
    ('tick_mode', "'auto' (default: joint_state, timer with sim time), 'timer', 'joint_state'"),
    ('thread_priority', 'SCHED_FIFO priority of the control thread (default 50; 0: none)'),
    ('cpu_affinity', 'CPUs of the control thread (default []: any)'),
    ('flight_recorder_dir', "where the last 2 s go when something goes wrong ('': off)"),
    ('autostart', 'configure + activate at start (default true)'),
    ('executor', "'events' (default) or 'single_threaded'"),
    ('sensor_qos', "'best_effort' (default) or 'reliable' inputs"),
)


def main(args: list[str] | None = None) -> int:
    """Run the node until SIGINT/SIGTERM (0); 1 if the parameters or the URDF are invalid."""
    if wants_help(args):
        print_help('controller', 'Adaptive hybrid force/motion controller (managed node '
                   "'hybrid_force_controller'): joint_states + wrench in, efforts out.",
                   HELP_PARAMETERS)
        return 0

    def make_node() -> ControllerNode:
        node = ControllerNode()
        node.schedule_this_thread()
        return node
    return run_node(make_node, 'hybrid_force_controller', args, cell=True)


if __name__ == '__main__':
    sys.exit(main())
