"""
``hybrid_force_controller`` managed node: messages -> ControllerRuntime -> messages.

Lifecycle: *configure* loads the robot model (``robot_description`` parameter, a ``.xacro``
path, the ``robot_description`` topic, or the bundled arm with ``use_bundled_model``) and
the parameters, and subscribes the inputs; *activate* starts commanding (the runtime
restarts, so the reference blends from the arm's position and velocity: no effort jump);
*deactivate* stops commanding (the hardware keeps its own hold); *cleanup* drops the model.
``autostart`` (default true) configures and activates at start. Parameter services work
in every state: before configure only the model-free checks run, the rest at configure.

Topics are relative, so ``-r __ns:=/arm1`` moves them all (``/diagnostics`` stays absolute):
subscribes ``joint_states``, ``force_torque_sensor_broadcaster/wrench``, ``~/reference``;
publishes ``effort_controller/commands`` every tick and ``~/x``, ``~/x_desired``,
``~/wrench``, ``~/wrench_desired``, ``~/error``, ``~/theta_hat`` at ``telemetry_rate_hz``.
QoS: :mod:`.qos`. ``/diagnostics`` (1 Hz) adds the input-to-command delay (joint-state
stamp to effort published, node clock), the tick period and the commands/s.
"""
from __future__ import annotations

from collections import Counter
import sys
import time
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, WrenchStamped
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from sensor_msgs.msg import JointState
from std_msgs.msg import String

from .cdr import read_joint_state, read_wrench_stamped
from .diagnostics import controller_status, EVENT_COUNTERS
from .loop_timing import DelayStats, RateMeter
from .model_source import expand_description, missing_description_hint
from .node_params import check_choice, CONTROLLER_NODE_SCHEMA, SENSOR_QOS, TICK_MODES
from .parameters import check_values, declare_schema, ParameterBinder
from .qos import DEFAULT_QOS, DESCRIPTION_QOS, sensor_in_qos
from .runner import EXECUTORS, print_help, run_node, wants_help
from .telemetry import ControllerOutputs
from ..core.loop_stats import LoopStats
from ..core.params import build_params, CONTROLLER_SCHEMA, MODEL_SCHEMA
from ..core.params import ParameterValidationError
from ..core.robot_model import RobotModel
from ..core.runtime import ControllerRuntime, InputError, Mode

__all__ = ['ControllerNode', 'main']

TOPIC_JOINT_STATES = 'joint_states'
TOPIC_WRENCH = 'force_torque_sensor_broadcaster/wrench'
TOPIC_DESCRIPTION = 'robot_description'
_OK, _FAIL = TransitionCallbackReturn.SUCCESS, TransitionCallbackReturn.FAILURE
WATCHDOG_PERIODS = 5  # tick_mode joint_state: the watchdog checks every 5 periods
MARGIN_EVERY = 10  # diagnostics periods between two delay-margin evaluations
STATS_WINDOW = 30000  # ticks (30 s at 1 kHz) behind the /diagnostics timing figures


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
        self.binder = ParameterBinder(self, CONTROLLER_SCHEMA, self._validate,
                                      self._install, unit=('n',))
        self.node_binder = ParameterBinder(
            self, [s for s in CONTROLLER_NODE_SCHEMA if s.name == 'telemetry_rate_hz'],
            lambda v: check_values(CONTROLLER_NODE_SCHEMA, v), self._install_node_values)
        self.errors: Counter[str] = Counter()
        self._node_clock = self.get_clock()  # the node clock (sim time with use_sim_time)
        self.state_label, self.last_error = 'unconfigured', ''
        self.runtime: ControllerRuntime | None = None
        self.model: RobotModel | None = None
        self._description_msg: str | None = None
        self._entities: list[tuple[Callable, Any]] = []
        self._tick_timer = self._watchdog = None
        self._reset_timing()
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', DEFAULT_QOS)
        self.create_timer(1.0, self._guarded('diagnostics', self._on_diagnostics))
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

    def _reset_timing(self) -> None:
        self.loop_stats, self.delay = LoopStats(STATS_WINDOW), DelayStats(STATS_WINDOW)
        self.commands = RateMeter()
        self._last = None
        self._mode, self._k_tick, self._t_state, self._t_tick = None, 0, 0.0, -1.0
        self._events: dict[str, int] = {}
        self._k_diag, self._margin_ms = 0, float('inf')
        self._decimation = self._decimation_for(self.node_values['telemetry_rate_hz'])

    def _decimation_for(self, telemetry_rate_hz: float) -> int:
        """Telemetry every k-th tick (0: never)."""
        rate = float(self.get_parameter('rate_hz').value)
        return 0 if telemetry_rate_hz <= 0.0 else max(1, round(rate / telemetry_rate_hz))

    def _install_node_values(self, values: dict[str, Any]) -> None:
        self._decimation = self._decimation_for(values['telemetry_rate_hz'])

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
        if self.runtime is not None and not isinstance(validated, dict):
            self.runtime.set_params(validated)

    # ------------------------------------------------------------------ lifecycle
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.model = self._load_model()
            self.runtime = ControllerRuntime(
                self.model, build_params(self.model, self._current_values()))
        except ValueError as exc:
            self.model = self.runtime = None
            self.last_error = str(exc)
            self.get_logger().error(f'configure failed: {exc}')
            return _FAIL
        self._ran = False  # a fresh runtime starts from the arm by itself
        self.outputs = ControllerOutputs(self, self.model.base_link, self.model.n,
                                         self.model.theta_names)
        qos_in = sensor_in_qos(self.node_values['sensor_qos'], self.node_values['sensor_depth'])
        for name, topic, kind, callback, qos, raw in (  # raw: read from the CDR bytes
                ('joint_states', TOPIC_JOINT_STATES, JointState, self._on_joint_state, qos_in,
                 True),
                ('wrench', TOPIC_WRENCH, WrenchStamped, self._on_wrench, qos_in, True),
                ('reference', '~/reference', PointStamped, self._on_reference, DEFAULT_QOS,
                 False)):
            sub = self.create_subscription(kind, topic, self._guarded(name, callback), qos,
                                           raw=raw)
            self._entities.append((self.destroy_subscription, sub))
        self.state_label = 'inactive'
        inputs = self._topic(TOPIC_JOINT_STATES)
        self.get_logger().info(f"configured: {self.model.n} joints, base '{self.model.base_link}'"
                               f', inputs {inputs}, commands {self.outputs.pub_tau.topic_name}')
        return _OK

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self._ran:  # re-activation: the next tick starts again from the arm's state
            self.runtime.restart()
        self._ran = True
        self._reset_timing()
        period = self._period = 1.0 / self.runtime.params.runtime.rate_hz
        if self._tick_mode() == 'timer':
            self._tick_timer = self.create_timer(period, self._guarded('tick', self._tick))
        else:
            self._watchdog = self.create_timer(WATCHDOG_PERIODS * period,
                                               self._guarded('watchdog', self._on_watchdog))
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
        for timer in (self._tick_timer, self._watchdog):
            if timer is not None:
                self.destroy_timer(timer)
        self._tick_timer = self._watchdog = None
        self.state_label = 'inactive'
        self.get_logger().info('inactive: no commands (the hardware holds)')
        return _OK

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        for destroy, entity in self._entities:
            destroy(entity)
        self._entities.clear()
        if self.runtime is not None:
            self.outputs.destroy()
        self.runtime = self.model = None
        self.state_label = 'unconfigured'
        return _OK

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.state_label == 'active':
            self.on_deactivate(state)
        if self.state_label == 'inactive':
            self.on_cleanup(state)
        self.state_label = 'finalized'
        return _OK

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

    def _now(self) -> float:
        return self._node_clock.now().nanoseconds * 1e-9

    def _on_joint_state(self, raw: bytes) -> None:
        msg = read_joint_state(raw)
        t = msg.stamp_s if msg.stamp_s > 0.0 else self._now()  # unstamped: reception time
        self.runtime.on_joint_state(msg.names, msg.position, msg.velocity, t)
        new, self._t_state = t > self._t_state, t
        if new and self._watchdog is not None:  # tick_mode joint_state, active: a new state
            self._tick(t)

    def _on_wrench(self, raw: bytes) -> None:
        msg = read_wrench_stamped(raw)
        t = msg.stamp_s if msg.stamp_s > 0.0 else self._now()
        self.runtime.on_wrench(msg.frame_id, msg.force, t)

    def _on_reference(self, msg: PointStamped) -> None:
        if msg.header.frame_id not in ('', self.model.base_link):
            raise InputError(f"reference frame '{msg.header.frame_id}' is not "
                             f"'{self.model.base_link}' (no TF here)")
        self.runtime.on_reference((msg.point.x, msg.point.y, msg.point.z))

    def _on_watchdog(self) -> None:
        """
        Tick anyway after 2 periods without a tick, or when the clock jumped back.

        tick_mode joint_state: a stale input or a restarted clock (whose joint states the
        runtime refuses as older until a tick restarts it) still reaches the runtime.
        """
        since = self._now() - self._t_tick
        if since >= 2.0 * self._period or since < -self._period:
            self._tick()

    def _tick(self, t_input: float = 0.0) -> None:
        """
        Run one tick at the node clock's time.

        Never before ``t_input``, the stamp of the joint state that triggered it (with sim
        time the /clock update may arrive after the state).
        """
        t_start = time.perf_counter()
        now_ns = max(self._node_clock.now().nanoseconds, round(t_input * 1e9))
        self._t_tick = now_ns * 1e-9
        out = self._last = self.runtime.tick(self._t_tick)
        if out.tau is not None:
            self.outputs.publish_effort(out.tau)  # delay: node clock at the tick + elapsed
            self.delay.record(self._t_tick + (time.perf_counter() - t_start) - self._t_state)
            self.commands.count += 1
            self._k_tick += 1
            if self._decimation and self._k_tick % self._decimation == 0:
                self.outputs.publish_telemetry(out, now_ns)
        if out.mode != self._mode:  # one call site per severity: rclpy refuses to mix them
            self._mode = out.mode
            if out.mode in (Mode.SAFE, Mode.NO_SURFACE):
                self.get_logger().error(f'mode {out.mode.value}: {out.status}')
            else:
                self.get_logger().info(f'mode {out.mode.value}: {out.status}')
        self.loop_stats.record(t_start, time.perf_counter())

    def _on_diagnostics(self) -> None:
        extra = {'lifecycle_state': self.state_label,
                 'commands_per_s': self.commands.rate(time.monotonic()),
                 **self.delay.summary('delay')}
        new_events: dict[str, int] = {}
        if self.runtime is not None:
            counts = {k: self.runtime.counters[k] for k in EVENT_COUNTERS}
            new_events = {k: v - self._events.get(k, 0) for k, v in counts.items()}
            self._events = counts
            self._k_diag += 1
            if self._k_diag % MARGIN_EVERY == 1:  # ~20 ms of work: not every second
                self._margin_ms = self.runtime.delay_margin() * 1e3
            extra['delay_margin_ms'] = self._margin_ms
        if self.last_error and self.runtime is None:
            extra['configure_error'] = self.last_error
        self.pub_diag.publish(controller_status(
            self.get_clock().now().to_msg(), self.get_name(), self.runtime, new_events,
            self.loop_stats.summary(), self.errors, extra, self.get_fully_qualified_name()))


HELP_PARAMETERS = (
    ('robot_description', "URDF XML, .urdf or .xacro path ('': robot_description topic)"),
    ('use_bundled_model', "true: the paper's 2-link arm when robot_description is ''"),
    ('joints', 'controlled joints, in the order of the effort command'),
    ('f_d, n', 'desired normal force (N) and contact normal (base frame)'),
    ('lambda1, lambda2, gamma', 'gains of eqs. (11) and (26)'),
    ('rate_hz', 'control rate (default 1000)'),
    ('telemetry_rate_hz', 'rate of ~/x ... ~/theta_hat (default 100)'),
    ('tick_mode', "'auto' (default: joint_state, timer with sim time), 'timer', 'joint_state'"),
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
    return run_node(ControllerNode, 'hybrid_force_controller', args)


if __name__ == '__main__':
    sys.exit(main())
