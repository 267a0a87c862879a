"""
The yardstick of ``bench --ros``: a bare rclpy node with the controller's I/O and no control.

It subscribes ``joint_states`` and ``force_torque_sensor_broadcaster/wrench`` (raw, KEEP_LAST
1, best effort, like the controller) and publishes one ``Float64MultiArray`` of as many
zeros as the joint state has positions on ``bare_node/commands`` for each joint state, on an
EventsExecutor, kept serialized and published as bytes as the controller's effort is. What
the controller costs beyond this is what its control costs.
"""
from __future__ import annotations

import array
import sys
from typing import Sequence

from geometry_msgs.msg import WrenchStamped
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from ..common.cdr import RawMessage, read_joint_state, read_wrench_stamped
from ..common.qos import COMMAND_QOS, sensor_in_qos
from ..common.runner import run_node

__all__ = ['BareNode', 'TOPIC_BARE_COMMANDS', 'main']

TOPIC_BARE_COMMANDS = 'bare_node/commands'


class BareNode(Node):
    """Decode both inputs, publish a command per joint state (kwargs go to ``Node``)."""

    def __init__(self, **kwargs) -> None:
        super().__init__('bare_node', **kwargs)
        self.msg = self._message(2)
        self.pub = self.create_publisher(Float64MultiArray, TOPIC_BARE_COMMANDS, COMMAND_QOS)
        qos = sensor_in_qos()
        self.create_subscription(JointState, 'joint_states', self._on_joint_state, qos, raw=True)
        self.create_subscription(WrenchStamped, 'force_torque_sensor_broadcaster/wrench',
                                 self._on_wrench, qos, raw=True)

    @staticmethod
    def _message(n: int) -> RawMessage:
        return RawMessage('float64_array', Float64MultiArray(data=array.array('d', bytes(8 * n))))

    def _on_joint_state(self, raw: bytes) -> None:
        state = read_joint_state(raw)
        if len(self.msg.arrays[0]) != len(state.position):
            self.msg = self._message(len(state.position))
        self.pub.publish(self.msg.serialized())

    def _on_wrench(self, raw: bytes) -> None:
        read_wrench_stamped(raw)


def main(args: Sequence[str] | None = None) -> int:
    """Run the bare node until SIGINT/SIGTERM."""
    return run_node(BareNode, 'bare_node', list(args) if args is not None else None)


if __name__ == '__main__':
    sys.exit(main())
