"""
The controller's outgoing messages, built once and refilled in place.

:class:`EffortOutput` is the effort publisher of the control thread (every tick);
:class:`ControllerOutputs` the telemetry publishers of the controller node (``~/x``,
``~/x_desired``, ``~/wrench``, ``~/wrench_desired``, ``~/error``, ``~/theta_hat``,
``~/stiffness_estimate``, ``~/surface_normal``; at ``telemetry_rate_hz``, from the latest
tick, on the node's thread). ``~/surface_normal`` (geometry_msgs/Vector3Stamped, base frame)
is the normal the controller uses: the ``n`` parameter, or with ``n_estimation`` its
estimate n_hat (core/runtime/surface.py). The effort and theta_hat data live in
``array.array('d')`` buffers that numpy views write into, so a tick allocates no message.
"""
from __future__ import annotations

import array
from typing import Any, Sequence

from geometry_msgs.msg import PointStamped, Vector3Stamped, WrenchStamped
import numpy as np
from std_msgs.msg import Float64, Float64MultiArray, MultiArrayDimension, MultiArrayLayout

from ..common.cdr import RawMessage
from ..common.qos import COMMAND_QOS, TELEMETRY_QOS

__all__ = ['ControllerOutputs', 'EffortOutput', 'TOPIC_COMMANDS']

TOPIC_COMMANDS = 'effort_controller/commands'


def _buffer_msg(size: int, layout: MultiArrayLayout | None = None
                ) -> tuple[Float64MultiArray, np.ndarray]:
    """Make a Float64MultiArray whose data is a fixed array.array, and a numpy view of it."""
    msg = Float64MultiArray(data=array.array('d', bytes(8 * size)))
    if layout is not None:
        msg.layout = layout
    return msg, np.frombuffer(msg.data, dtype=np.float64)


class EffortOutput:
    """
    The effort publisher and its message (the control thread's only output).

    The message is kept serialized and published as bytes (cdr.py ``RawMessage``).
    """

    def __init__(self, node: Any, topic: str, n_joints: int) -> None:
        self.pub_tau = node.create_publisher(Float64MultiArray, topic, COMMAND_QOS)
        self.tau_msg = RawMessage('float64_array', _buffer_msg(n_joints)[0])
        self.tau_view = self.tau_msg.arrays[0]

    def publish(self, tau: np.ndarray) -> None:
        """Publish the joint efforts (command order)."""
        self.tau_view[:] = tau
        self.pub_tau.publish(self.tau_msg.serialized())


class ControllerOutputs:
    """Telemetry publishers and reusable messages of one controller node."""

    def __init__(self, node: Any, base_frame: str, theta_names: Sequence[str]) -> None:
        self.node = node
        p = len(theta_names)
        layout = MultiArrayLayout(dim=[MultiArrayDimension(label=','.join(theta_names),
                                                           size=p, stride=p)])
        self.theta_msg, self.theta_view = _buffer_msg(p, layout)
        self.x, self.x_d = PointStamped(), PointStamped()
        self.f, self.f_d = WrenchStamped(), WrenchStamped()
        self.e, self.n = Vector3Stamped(), Vector3Stamped()
        self.stamped = (self.x, self.x_d, self.f, self.f_d, self.e, self.n)
        for msg in self.stamped:
            msg.header.frame_id = base_frame
        self.vectors = (self.x.point, self.x_d.point, self.f.wrench.force,
                        self.f_d.wrench.force, self.e.vector)
        topics = (('~/x', self.x), ('~/x_desired', self.x_d), ('~/wrench', self.f),
                  ('~/wrench_desired', self.f_d), ('~/error', self.e),
                  ('~/surface_normal', self.n))
        self.telemetry = [(node.create_publisher(type(m), t, TELEMETRY_QOS), m)
                          for t, m in topics]
        self.telemetry.append((node.create_publisher(Float64MultiArray, '~/theta_hat',
                                                     TELEMETRY_QOS), self.theta_msg))
        self.k_msg = Float64()  # the stiffness estimate, N/m (NaN while unknown)
        self.telemetry.append((node.create_publisher(Float64, '~/stiffness_estimate',
                                                     TELEMETRY_QOS), self.k_msg))

    def publish_telemetry(self, out: Any, stamp_ns: int) -> None:
        """Publish the tick's positions, forces, error and theta_hat (base frame)."""
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        for msg in self.stamped:
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
        for target, v in zip(self.vectors, (out.x_W, out.x_d_W, out.f_W, out.f_d_W, out.e_W)):
            target.x, target.y, target.z = float(v[0]), float(v[1]), float(v[2])
        if out.n_W is not None:
            v, target = out.n_W, self.n.vector
            target.x, target.y, target.z = float(v[0]), float(v[1]), float(v[2])
        self.theta_view[:] = out.theta_hat
        self.k_msg.data = float(out.k_hat)
        for publisher, msg in self.telemetry:
            publisher.publish(msg)

    def destroy(self) -> None:
        """Destroy every publisher (lifecycle cleanup)."""
        for publisher, _ in self.telemetry:
            self.node.destroy_publisher(publisher)
