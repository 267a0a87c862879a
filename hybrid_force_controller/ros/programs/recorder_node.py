"""
``BagRecorder``: a minimal rosbag2 recorder node (raw CDR in, MCAP out).

Subscribes without deserializing (``raw=True``) and stamps every message with the node
clock at reception (sim time when ``use_sim_time`` is set), like ``ros2 bag record``.
Topic names are relative (except ``/diagnostics``), so the recorder follows the namespace
(``-r __ns:=/arm1`` records ``/arm1/joint_states`` ...); the bag stores the resolved names.
``python -m hybrid_force_controller.ros.programs.recorder_node BAG [--ros-args ...]`` records until
SIGINT/SIGTERM, then closes the bag.
"""
from __future__ import annotations

import atexit
from functools import partial
import importlib
from pathlib import Path
import sys
from typing import Sequence

from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from ..common.runner import run_node, wants_help
from ...tools.bag_io import BagWriter, LATCHED_TOPICS, RECORD_TOPICS

__all__ = ['BagRecorder', 'main', 'message_class', 'relative']


def message_class(msgtype: str) -> type:
    """Return the rclpy message class of ``'pkg/msg/Type'``."""
    package, kind, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.{kind}'), name)


def relative(topic: str) -> str:
    """``/joint_states`` -> ``joint_states`` (follows the namespace); ``/diagnostics`` stays."""
    return topic if topic == '/diagnostics' else topic.lstrip('/')


class BagRecorder(Node):
    """
    Record ``topics`` into a new MCAP bag at ``bag_path``.

    Parameters
    ----------
    bag_path : str or pathlib.Path
        Bag directory to create (must not exist).
    topics : sequence of (str, str)
        ``(topic, msgtype)`` pairs; default
        :data:`~hybrid_force_controller.tools.bag_io.RECORD_TOPICS` (made relative, see
        :func:`relative`).
    node_name : str
        Node name.
    depth : int
        Subscription queue depth (reliable, volatile): 1 s of the 1 kHz topics.
    start_with : sequence of str
        Topics (as in ``topics``) that begin the bag: until each has been received once, the
        other topics' messages are dropped (the latched ones are always kept). A subscription
        can match seconds after its neighbours on a busy machine; the demo starts its bag with
        the loop's joint states and commands so every topic covers the same run. Default:
        none (everything from the start).
    **kwargs
        Passed to :class:`rclpy.node.Node` (``context=``, ``parameter_overrides=`` ...).

    """

    def __init__(self, bag_path: str | Path,
                 topics: Sequence[tuple[str, str]] = tuple(RECORD_TOPICS),
                 node_name: str = 'bag_recorder', depth: int = 1000,
                 start_with: Sequence[str] = (), **kwargs) -> None:
        super().__init__(node_name, **kwargs)
        qos = QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        resolved = []
        for topic, msgtype in topics:
            name = self.resolve_topic_name(relative(topic))
            resolved.append((name, msgtype))
        self.writer = BagWriter(bag_path, resolved)
        self._awaited = {self.resolve_topic_name(relative(t)) for t in start_with}
        self._latched = {name for name, _ in resolved
                         if any(name.endswith(t) for t in LATCHED_TOPICS)}  # under any namespace
        # a Ctrl-C that lands while the node is still being built ends run_node before it has
        # the node to destroy (seen once under taskset -c 0: the bag had no metadata.yaml);
        # the bag is closed at exit whatever the path (close() is idempotent)
        atexit.register(self.writer.close)
        for name, msgtype in resolved:
            self.create_subscription(message_class(msgtype), name, partial(self.record, name),
                                     latched if name in self._latched else qos, raw=True)
        self.get_logger().info(f'recording {len(topics)} topics to {self.writer.path}')

    def record(self, topic: str, raw_cdr: bytes) -> bool:
        """
        Write one received message; never raises (a callback exception kills the node).

        Returns
        -------
        bool
            Whether the message was written (False also before the bag began: ``start_with``).

        """
        if self._awaited:
            self._awaited.discard(topic)
            if self._awaited and topic not in self._latched:
                return False
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


def main(args: Sequence[str] | None = None) -> int:
    """Record into the bag directory given as the first argument until SIGINT/SIGTERM."""
    argv = list(sys.argv[1:] if args is None else args)
    head = argv[:argv.index('--ros-args')] if '--ros-args' in argv else argv
    if wants_help(argv) or len(head) != 1:
        print('usage: python -m hybrid_force_controller.ros.programs.recorder_node BAG_DIR '
              '[--ros-args ...]\nRecords the controller, sim and diagnostics topics to a new '
              'MCAP bag until SIGINT/SIGTERM.')
        return 0 if wants_help(argv) else 2
    return run_node(lambda: BagRecorder(head[0]), 'recorder', ['recorder', *argv[1:]])


if __name__ == '__main__':
    sys.exit(main())
