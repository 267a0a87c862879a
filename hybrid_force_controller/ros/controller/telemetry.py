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
import math
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
    """
    Telemetry publishers and their messages, kept serialized and refilled in place (cdr.py).

    Publishing bytes skips rclpy's conversion of a Python message, about a third of the
    telemetry's cost (docs/results.md, section 12).
    """

    TOPICS = (('~/x', PointStamped, 'point_stamped'),
              ('~/x_desired', PointStamped, 'point_stamped'),
              ('~/wrench', WrenchStamped, 'wrench_stamped'),
              ('~/wrench_desired', WrenchStamped, 'wrench_stamped'),
              ('~/error', Vector3Stamped, 'vector3_stamped'),
              ('~/surface_normal', Vector3Stamped, 'vector3_stamped'))

    def __init__(self, node: Any, base_frame: str, theta_names: Sequence[str]) -> None:
        self.node = node
        p = len(theta_names)
        layout = MultiArrayLayout(dim=[MultiArrayDimension(label=','.join(theta_names),
                                                           size=p, stride=p)])
        self.telemetry: list[tuple[Any, RawMessage]] = []
        for topic, msg_type, kind in self.TOPICS:
            template = msg_type()
            template.header.frame_id = base_frame
            self.telemetry.append((node.create_publisher(msg_type, topic, TELEMETRY_QOS),
                                   RawMessage(kind, template)))
        self.stamped = [m for _, m in self.telemetry]
        self.vectors = [m.arrays[0] for m in self.stamped]  # x, x_d, f, f_d, e, n
        theta = RawMessage('float64_array', _buffer_msg(p, layout)[0])
        self.theta_view = theta.arrays[0]
        self.telemetry.append((node.create_publisher(Float64MultiArray, '~/theta_hat',
                                                     TELEMETRY_QOS), theta))
        k = RawMessage('float64', Float64(data=math.nan))
        self.k_view = k.arrays[0]  # the stiffness estimate, N/m (NaN while unknown)
        self.telemetry.append((node.create_publisher(Float64, '~/stiffness_estimate',
                                                     TELEMETRY_QOS), k))

    def publish_telemetry(self, out: Any, stamp_ns: int) -> None:
        """Publish the tick's positions, forces, error, normal and theta_hat (base frame)."""
        for msg in self.stamped:
            msg.set_stamp(stamp_ns)
        for target, v in zip(self.vectors, (out.x_W, out.x_d_W, out.f_W, out.f_d_W, out.e_W)):
            target[:] = v
        if out.n_W is not None:
            self.vectors[5][:] = out.n_W
        self.theta_view[:] = out.theta_hat
        self.k_view[0] = out.k_hat
        for publisher, msg in self.telemetry:
            publisher.publish(msg.serialized())

    def destroy(self) -> None:
        """Destroy every publisher (lifecycle cleanup)."""
        for publisher, _ in self.telemetry:
            self.node.destroy_publisher(publisher)
