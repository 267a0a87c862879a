"""
Two arms side by side: a sim and a controller in ``/arm1``, another pair in ``/arm2``.

Every topic is relative, so ``-r __ns:=/armN`` moves them all (only ``/diagnostics`` stays
global). Checked over real DDS: the graph (who subscribes and publishes what), and that
each pair closes its own loop (different ``f_d`` per arm, each sim's true force near its
own controller's f_d), with nothing on the global topics.
"""
from __future__ import annotations

import threading

from geometry_msgs.msg import WrenchStamped
from helpers.ros import domain_id, NodeProcess, Spun, wait_for
import numpy as np
import pytest
from rclpy.node import Node
from rclpy.qos import QoSProfile


CTRL = 'hybrid_force_controller.ros.controller.controller_node'
F_D = {'/arm1': 1.0, '/arm2': 2.0}


class _Forces(Node):
    """True contact force of each arm's sim."""

    def __init__(self, context) -> None:
        super().__init__('namespace_watcher', context=context)
        self.lock = threading.Lock()
        self.force: dict[str, list[float]] = {ns: [] for ns in F_D}
        for ns in F_D:
            self.create_subscription(WrenchStamped, f'{ns}/sim/contact_wrench',
                                     lambda m, ns=ns: self._on_force(ns, m), QoSProfile(depth=100))

    def _on_force(self, ns: str, msg) -> None:
        with self.lock:
            self.force[ns].append(-msg.wrench.force.y)  # n = (0, -1, 0)

    def recent(self, ns: str, k: int) -> np.ndarray:
        with self.lock:
            return np.array(self.force[ns][-k:])


@pytest.fixture(scope='module')
def two_arms(tmp_path_factory):
    logs = tmp_path_factory.mktemp('namespaces')
    domain = domain_id('namespaces')
    procs = []
    for ns, f_d in F_D.items():
        remap = ['-r', f'__ns:={ns}']
        procs.append(NodeProcess('sim_node.sim_node', logs / f'sim{ns[-1]}.log', domain, remap))
        procs.append(NodeProcess(CTRL, logs / f'controller{ns[-1]}.log', domain,
                                 [*remap, '-p', f'f_d:={f_d}']))
    spun = Spun(domain)
    try:
        w = spun.add(_Forces(spun.context))
        for p in procs:
            p.start()
        yield w, procs
    finally:
        for p in procs:
            p.stop()
        spun.close()


def _endpoints(node: Node, topic: str, publishers: bool) -> set[str]:
    info = (node.get_publishers_info_by_topic(topic) if publishers
            else node.get_subscriptions_info_by_topic(topic))
    return {f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in info}


def test_namespace_moves_every_topic(two_arms):
    w, procs = two_arms
    for ns in F_D:
        ctrl, sim = f'{ns}/hybrid_force_controller', f'{ns}/sim'
        rt = f'{ns}/_hybrid_force_controller_rt'  # the control thread's node (1 kHz I/O)
        expected = {
            (f'{ns}/joint_states', False): {rt}, (f'{ns}/joint_states', True): {sim},
            (f'{ns}/force_torque_sensor_broadcaster/wrench', False): {rt},
            (f'{ns}/effort_controller/commands', True): {rt},
            (f'{ns}/effort_controller/commands', False): {sim},
            (f'{ns}/hybrid_force_controller/x', True): {ctrl},
            (f'{ns}/robot_description', True): {sim},
        }
        for (topic, pub), nodes in expected.items():
            wait_for(lambda: nodes <= _endpoints(w, topic, pub),
                     f'{nodes} on {topic} ({"pub" if pub else "sub"})', alive=procs)
    for topic in ('/joint_states', '/effort_controller/commands',
                  '/force_torque_sensor_broadcaster/wrench'):
        assert not _endpoints(w, topic, True) and not _endpoints(w, topic, False), topic
    diag = _endpoints(w, '/diagnostics', True)
    assert {'/arm1/hybrid_force_controller', '/arm2/hybrid_force_controller'} <= diag


def test_two_loops_run_side_by_side(two_arms):
    w, procs = two_arms
    for ns, f_d in F_D.items():
        wait_for(lambda: len(w.recent(ns, 300)) == 300
                 and np.all(np.abs(w.recent(ns, 300) - f_d) < 0.1),
                 f'{ns}: 3 s of true force within 0.1 N of {f_d} N', alive=procs)
