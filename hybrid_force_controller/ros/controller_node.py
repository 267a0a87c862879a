"""``hybrid_force_controller`` node: messages -> :class:`~.runtime.ControllerRuntime` -> messages.

Subscribes ``/joint_states``, ``/force_torque_sensor_broadcaster/wrench`` and
``~/reference``; a timer at ``rate_hz`` on the node clock (``use_sim_time`` works) publishes
``/effort_controller/commands`` and, in the base frame, ``~/x``, ``~/x_desired``,
``~/wrench``, ``~/wrench_desired`` (force the tool exerts on the surface), ``~/error`` and
``~/theta_hat``. Every parameter of the schema is declared; sets are validated first.
"""
from __future__ import annotations

import sys
import time
from collections import Counter
from typing import Any, Callable

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PointStamped, Vector3Stamped, WrenchStamped
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, Header, MultiArrayDimension, MultiArrayLayout

from .diagnostics import INPUT_FAULTS, controller_status
from ..core.loop_stats import LoopStats
from ..core.params import CONTROLLER_SCHEMA, MODEL_SCHEMA
from ..core.robot_model import RobotModel
from .parameters import ParameterBinder, declare_schema, run_node
from ..core.params import build_params
from ..core.runtime import ControllerRuntime, InputError, Mode, TickOutput

__all__ = ['ControllerNode', 'main']


def _seconds(stamp, fallback: float) -> float:
    """Header stamp in seconds, or ``fallback`` for an unstamped (zero) header."""
    t = Time.from_msg(stamp).nanoseconds * 1e-9
    return t if t > 0.0 else fallback


class ControllerNode(Node):
    """Thin adapter around :class:`~.runtime.ControllerRuntime` (kwargs go to ``Node``)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('hybrid_force_controller', **kwargs)
        values = declare_schema(self, CONTROLLER_SCHEMA, unit=('n',))
        model_values = declare_schema(self, MODEL_SCHEMA)
        self.model = RobotModel.from_parameters(model_values, values['joints'])
        self.runtime = ControllerRuntime(self.model, build_params(self.model, values))
        self.binder = ParameterBinder(self, CONTROLLER_SCHEMA, self.runtime.validate,
                                      self.runtime.set_params, unit=('n',))
        self.errors: Counter[str] = Counter()
        self.base_frame = self.model.base_link
        self._mode: Mode | None = None
        self._faults = 0
        qos = QoSProfile(depth=10)
        self.create_subscription(JointState, '/joint_states',
                                 self._guarded('joint_states', self._on_joint_state), qos)
        self.create_subscription(WrenchStamped, '/force_torque_sensor_broadcaster/wrench',
                                 self._guarded('wrench', self._on_wrench), qos)
        self.create_subscription(PointStamped, '~/reference',
                                 self._guarded('reference', self._on_reference), qos)
        self.pub_tau = self.create_publisher(Float64MultiArray, '/effort_controller/commands', qos)
        self.pub_x = self.create_publisher(PointStamped, '~/x', qos)
        self.pub_x_d = self.create_publisher(PointStamped, '~/x_desired', qos)
        self.pub_f = self.create_publisher(WrenchStamped, '~/wrench', qos)
        self.pub_f_d = self.create_publisher(WrenchStamped, '~/wrench_desired', qos)
        self.pub_e = self.create_publisher(Vector3Stamped, '~/error', qos)
        self.pub_theta = self.create_publisher(Float64MultiArray, '~/theta_hat', qos)
        self.pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', qos)
        p = len(self.model.theta_names)  # the theta_hat layout never changes: build it once
        self._theta_layout = MultiArrayLayout(dim=[MultiArrayDimension(
            label=','.join(self.model.theta_names), size=p, stride=p)])
        self.loop_stats = LoopStats()
        self._last: TickOutput | None = None
        self.timer = self.create_timer(1.0 / self.runtime.params.runtime.rate_hz,
                                       self._guarded('tick', self._on_timer))
        self.create_timer(1.0, self._guarded('diagnostics', self._on_diagnostics))

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

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

    def _on_joint_state(self, msg: JointState) -> None:
        self.runtime.on_joint_state(msg.name, msg.position, msg.velocity,
                                    _seconds(msg.header.stamp, self._now()))

    def _on_wrench(self, msg: WrenchStamped) -> None:
        f = msg.wrench.force
        self.runtime.on_wrench(msg.header.frame_id, (f.x, f.y, f.z),
                               _seconds(msg.header.stamp, self._now()))

    def _on_reference(self, msg: PointStamped) -> None:
        if msg.header.frame_id not in ('', self.base_frame):
            raise InputError(f"reference frame '{msg.header.frame_id}' is not "
                             f"'{self.base_frame}' (no TF here)")
        self.runtime.on_reference((msg.point.x, msg.point.y, msg.point.z))

    def _on_timer(self) -> None:
        t_start = time.perf_counter()
        now = self.get_clock().now()
        out = self._last = self.runtime.tick(now.nanoseconds * 1e-9)
        if out.tau is not None:
            messages = self._messages(out, now.to_msg())  # build all first: all or nothing
            for publisher, msg in messages:
                publisher.publish(msg)
        if out.mode != self._mode:  # one call site per severity: rclpy refuses to mix them
            self._mode = out.mode
            if out.mode in (Mode.SAFE, Mode.NO_SURFACE):
                self.get_logger().error(f'mode {out.mode.value}: {out.status}')
            else:
                self.get_logger().info(f'mode {out.mode.value}: {out.status}')
        self.loop_stats.record(t_start, time.perf_counter())

    def _on_diagnostics(self) -> None:
        faults = sum(self.runtime.counters[k] for k in INPUT_FAULTS)
        new_faults, self._faults = faults - self._faults, faults
        self.pub_diag.publish(controller_status(self.get_clock().now().to_msg(), self.get_name(),
                                                self.runtime, new_faults,
                                                self.loop_stats.summary(), self.errors))

    def _messages(self, out: TickOutput, stamp) -> list[tuple[Any, Any]]:
        header = Header(stamp=stamp, frame_id=self.base_frame)
        x, x_d = PointStamped(header=header), PointStamped(header=header)
        f, f_d = WrenchStamped(header=header), WrenchStamped(header=header)
        e = Vector3Stamped(header=header)
        for target, v in ((x.point, out.x_W), (x_d.point, out.x_d_W), (f.wrench.force, out.f_W),
                          (f_d.wrench.force, out.f_d_W), (e.vector, out.e_W)):
            target.x, target.y, target.z = (float(c) for c in v)
        tau = Float64MultiArray(data=[float(c) for c in out.tau])
        theta = Float64MultiArray(layout=self._theta_layout,
                                  data=[float(c) for c in out.theta_hat])
        return [(self.pub_tau, tau), (self.pub_x, x), (self.pub_x_d, x_d), (self.pub_f, f),
                (self.pub_f_d, f_d), (self.pub_e, e), (self.pub_theta, theta)]


def main(args: list[str] | None = None) -> int:
    """Run the node until shutdown; 1 if the parameters or the URDF are invalid."""
    return run_node(ControllerNode, 'hybrid_force_controller', args)


if __name__ == '__main__':
    sys.exit(main())
