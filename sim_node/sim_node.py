"""``sim`` node: the simulated arm against the elastic surface, as a ros2_control-like robot.

Publishes ``/joint_states``, ``/force_torque_sensor_broadcaster/wrench`` (force the
environment exerts on the tool, in ``tool0``, with noise) and ``/sim/contact_wrench``
(true force the tool exerts on the surface, base frame); takes efforts from
``/effort_controller/commands``. Until the first valid command the arm is held still
(brakes). Real-time mode steps on a wall timer. Lockstep mode owns the time: it publishes
the state and ``/clock`` (equal stamps) and steps once per received command; a 0.2 s wall
watchdog steps anyway (held or zero effort, brakes before the first command), so a lost
message cannot deadlock the loop and a controller with ``use_sim_time`` gets its first tick.
The surface (``stiffness``, ``surface_point``, ``surface_normal``, ``surface_enabled``) can be
set at run time; a set is validated as a whole and swapped in between two steps.
"""
from __future__ import annotations

import sys
import time
from typing import Any, Callable

import numpy as np
from geometry_msgs.msg import WrenchStamped
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.time import Time
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from hybrid_force_controller.core.environment import (ElasticSurface, SurfaceError,
                                                 sensor_wrench_from_f_W)
from hybrid_force_controller.core.params import (MODEL_SCHEMA, ParameterValidationError,
                                            ParamSpec as _S)
from hybrid_force_controller.core.robot_model import RobotModel
from hybrid_force_controller.ros.parameters import ParameterBinder, declare_schema, run_node
from hybrid_force_controller.core.simulator import ArmSimulator, Measurement

__all__ = ['SIM_SCHEMA', 'SimNode', 'main']

WATCHDOG_S = 0.2
SURFACE = ('stiffness', 'surface_point', 'surface_normal', 'surface_enabled')  # settable
SIM_SCHEMA = tuple(_S(*a, read_only=a[0] not in SURFACE, **k) for *a, k in (
    ('rate_hz', 'double', 1000.0, 'Plant step rate, Hz (each step is 1/rate_hz).', 1.0, 1e5, {}),
    ('joints', 'string_array', ['joint1', 'joint2'], 'Joint order of states and commands.', {}),
    ('stiffness', 'double', 1700.0, 'Surface stiffness k, N/m.', 1e-6, 1e9, {}),
    ('surface_point', 'double_array', [],
     'Point of the undeformed surface, base frame, m ([] = tool start: touching, 0 N).', {}),
    ('surface_normal', 'double_array', [0.0, -1.0, 0.0], 'Surface normal (into it), base.', {}),
    ('surface_enabled', 'bool', True, 'false: no surface (free motion, e.g. contact loss).', {}),
    ('masses', 'double_array', [], 'True link masses, kg ([] = URDF).', {}),
    ('q0', 'double_array', [0.657, 0.913], 'Initial joint positions (joints order), rad.', {}),
    ('noise_sigma', 'double', 0.0, 'Force sensor noise sigma, N.', 0.0, 1e3, {}),
    ('seed', 'integer', 0, 'Noise seed.', 0, 2 ** 31 - 1, {}),
    ('substeps', 'integer', 4, 'Integration sub-steps per step.', 1, 1000, {}),
    ('command_timeout', 'double', 0.1, 'Zero effort after this long without a command, s '
     '(sim time in lockstep).', 1e-6, 60.0, {}),
    ('lockstep', 'bool', False, 'Own the time: publish /clock, step once per command.', {}),
))


class SimNode(Node):
    """The plant behind ROS topics (kwargs go to ``Node``)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__('sim', **kwargs)
        v = declare_schema(self, SIM_SCHEMA, unit=('surface_normal',))
        model = RobotModel.from_parameters(declare_schema(self, MODEL_SCHEMA), v['joints'])
        self.joints = list(v['joints'])
        if sorted(self.joints) != sorted(model.joint_names):
            raise ParameterValidationError(f'joints must be a permutation of {model.joint_names}')
        self.to_model = [self.joints.index(j) for j in model.joint_names]
        self.to_msg = [model.joint_names.index(j) for j in self.joints]
        q0 = np.asarray(v['q0'], dtype=float)[self.to_model]
        self.p0_W = model.kinematics(q0, np.zeros(model.n)).p_W
        plant = model.with_theta(v['masses']) if v['masses'] else model
        self.sim = ArmSimulator(plant, self._surface(v)[0], q0, substeps=v['substeps'],
                                noise_sigma=v['noise_sigma'], seed=v['seed'])
        self.binder = ParameterBinder(self, [s for s in SIM_SCHEMA if s.name in SURFACE],
                                      self._surface, self._set_surface, unit=('surface_normal',))
        self.dt, self.lockstep = 1.0 / v['rate_hz'], bool(v['lockstep'])
        self.command_timeout = v['command_timeout']
        self.base_frame, self.tool_frame = model.base_link, model.end_effector_link
        self.tau_cmd: np.ndarray | None = None
        self.t_cmd = self.t_pub = -np.inf
        self.counters = {'steps': 0, 'commands_rejected': 0, 'watchdog_steps': 0, 'errors': 0}
        qos = QoSProfile(depth=10)
        self.pub_js = self.create_publisher(JointState, '/joint_states', qos)
        self.pub_ft = self.create_publisher(WrenchStamped,
                                            '/force_torque_sensor_broadcaster/wrench', qos)
        self.pub_true = self.create_publisher(WrenchStamped, '/sim/contact_wrench', qos)
        self.pub_clock = self.create_publisher(ClockMsg, '/clock', qos) if self.lockstep else None
        self.create_subscription(Float64MultiArray, '/effort_controller/commands',
                                 self._guarded('command', self._on_command), qos)
        period, tick = ((WATCHDOG_S / 4, self._on_watchdog) if self.lockstep
                        else (self.dt, lambda: self._step(self._effort())))
        self.timer = self.create_timer(period, self._guarded('timer', tick),
                                       clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._publish(self.sim.measure())

    def _surface(self, v: dict[str, Any]) -> tuple[ElasticSurface | None]:
        """The surface the values describe (None when disabled); SurfaceError says why not."""
        if not isinstance(v['stiffness'], float) or not isinstance(v['surface_enabled'], bool):
            raise SurfaceError('stiffness must be a number and surface_enabled a bool')
        surface = ElasticSurface.create(v['stiffness'], v['surface_point'] or self.p0_W,
                                        v['surface_normal'])
        return (surface if v['surface_enabled'] else None,)

    def _set_surface(self, surface: tuple[ElasticSurface | None]) -> None:
        """Swap the surface in; the contact torque measure() cached for the old one is dropped."""
        self.sim.surface, self.sim._tau_c = surface[0], None

    def _guarded(self, name: str, callback: Callable) -> Callable:
        """Wrap a callback: exceptions are counted and logged (throttled), never raised."""
        def run(*args: Any) -> None:
            try:
                callback(*args)
            except Exception as exc:  # noqa: BLE001 - an escaping exception kills the node
                self.counters['errors'] += 1
                self.get_logger().error(f'{name} failed: {exc!r}', throttle_duration_sec=1.0)
        return run

    def _on_command(self, msg: Float64MultiArray) -> None:
        tau = np.asarray(msg.data, dtype=float)
        if tau.shape != (len(self.joints),) or not np.all(np.isfinite(tau)):
            self.counters['commands_rejected'] += 1
            self.get_logger().warning(f'rejected command {tau.tolist()}: need {len(self.joints)}'
                                      ' finite efforts; keeping the last valid one',
                                      throttle_duration_sec=1.0)
            return
        self.tau_cmd, self.t_cmd = tau[self.to_model], self._time()
        if self.lockstep:
            self._step(self.tau_cmd)

    def _on_watchdog(self) -> None:
        """Lockstep: step anyway when no command came for WATCHDOG_S (wall)."""
        if time.monotonic() - self.t_pub >= WATCHDOG_S:
            self.counters['watchdog_steps'] += 1
            self._step(self._effort())

    def _time(self) -> float:
        """Seconds on the clock that command_timeout uses: sim time in lockstep, else wall."""
        return self.sim.t if self.lockstep else time.monotonic()

    def _effort(self) -> np.ndarray | None:
        """Held command; zeros once it is older than command_timeout; None (brakes) before."""
        if self.tau_cmd is None or self._time() - self.t_cmd <= self.command_timeout:
            return self.tau_cmd
        self.get_logger().warning('no valid command within command_timeout: zero effort',
                                  throttle_duration_sec=1.0)
        return np.zeros_like(self.tau_cmd)

    def _step(self, tau: np.ndarray | None) -> None:
        """One step of 1/rate_hz (``None``: brakes hold the arm, time still advances)."""
        if tau is None:
            self.sim.t += self.dt
        meas = self.sim.measure() if tau is None else self.sim.step(tau, self.dt)
        self.counters['steps'] += 1
        self._publish(meas)

    def _publish(self, meas: Measurement) -> None:
        stamp = (Time(nanoseconds=round(meas.t * 1e9)) if self.lockstep
                 else self.get_clock().now()).to_msg()
        js = JointState(name=self.joints, position=meas.q[self.to_msg].tolist(),
                        velocity=meas.qdot[self.to_msg].tolist(),
                        effort=meas.tau[self.to_msg].tolist())
        F_ee = sensor_wrench_from_f_W(meas.R_W_ee, meas.f_W)
        ft, true = WrenchStamped(), WrenchStamped()
        for msg, frame, force in ((ft, self.tool_frame, F_ee),
                                  (true, self.base_frame, meas.f_true_W)):
            msg.header.frame_id = frame
            msg.wrench.force.x, msg.wrench.force.y, msg.wrench.force.z = map(float, force)
        for pub, msg in ((self.pub_js, js), (self.pub_ft, ft), (self.pub_true, true)):
            msg.header.stamp = stamp
            pub.publish(msg)
        if self.pub_clock is not None:
            self.pub_clock.publish(ClockMsg(clock=stamp))
        self.t_pub = time.monotonic()


def main(args: list[str] | None = None) -> int:
    """Run the simulator until shutdown; 1 if its parameters are invalid."""
    return run_node(SimNode, 'sim', args)


if __name__ == '__main__':
    sys.exit(main())
