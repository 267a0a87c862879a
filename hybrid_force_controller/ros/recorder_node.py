"""``BagRecorder``: a minimal rosbag2 recorder node (raw CDR in, MCAP out).

Subscribes without deserializing (``raw=True``) and stamps every message with the node
clock at reception (sim time when ``use_sim_time`` is set), like ``ros2 bag record``.
"""
from __future__ import annotations

import importlib
from functools import partial
from pathlib import Path
from typing import Sequence

from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from ..tools.bag_io import RECORD_TOPICS, BagWriter

__all__ = ['BagRecorder', 'message_class']


def message_class(msgtype: str) -> type:
    """The rclpy message class of ``'pkg/msg/Type'``."""
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


class BagRecorder(Node):
    """Record ``topics`` into a new MCAP bag at ``bag_path``.

    Parameters
    ----------
    bag_path : str or pathlib.Path
        Bag directory to create (must not exist).
    topics : sequence of (str, str)
        ``(topic, msgtype)`` pairs; default :data:`~hybrid_force_controller.tools.bag_io.RECORD_TOPICS`.
    node_name : str
        Node name.
    depth : int
        Subscription queue depth (reliable, volatile).
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context=``, ``parameter_overrides=`` ...).
    """

    def __init__(self, bag_path: str | Path,
                 topics: Sequence[tuple[str, str]] = tuple(RECORD_TOPICS),
                 node_name: str = 'bag_recorder', depth: int = 100, **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        self.writer = BagWriter(bag_path, list(topics))
        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
        for topic, msgtype in topics:
            self.create_subscription(message_class(msgtype), topic,
                                     partial(self.record, topic), qos, raw=True)
        self.get_logger().info(f'recording {len(topics)} topics to {self.writer.path}')

    def record(self, topic: str, raw_cdr: bytes) -> bool:
        """Write one received message; never raises (a callback exception kills the node).

        Returns
        -------
        bool
            Whether the message was written.
        """
        try:
            self.writer.write(topic, self.get_clock().now().nanoseconds, raw_cdr)
        except Exception as exc:  # noqa: BLE001 - log and keep the node alive
            self.get_logger().error(f'dropping message on {topic}: {exc}',
                                    throttle_duration_sec=1.0)
            return False
        return True

    def close(self) -> None:
        """Finish the bag (idempotent); later messages are dropped with an error log."""
        self.writer.close()

    def destroy_node(self) -> None:
        """Close the bag, then destroy the node."""
        try:
            self.close()
        except Exception as exc:  # noqa: BLE001 - still destroy the node
            self.get_logger().error(f'closing bag {self.writer.path} failed: {exc}')
        super().destroy_node()
