"""
Two arms side by side: a sim and a controller in ``/arm1``, another pair in ``/arm2``.

Every topic is relative, so ``-r __ns:=/armN`` moves them all (only ``/diagnostics`` stays
global). Checked over real DDS: the graph (who subscribes and publishes what), and that
each pair closes its own loop (different ``f_d`` per arm, each sim's true force near its
own controller's f_d), with nothing on the global topics, and both runs clean (no callback error,
no safe mode).
"""
from __future__ import annotations

from helpers.ros import CONTROLLER_MODULE, domain_id, NodeProcess, SIM_MODULE, Spun, wait_for
from helpers.watch import assert_clean_run, ForceLog
import numpy as np
import pytest
from rclpy.node import Node


F_D = {'/arm1': 1.0, '/arm2': 2.0}


@pytest.fixture(scope='module')
def two_arms(tmp_path_factory):
    """Yield a force log per arm (in its namespace) and the four processes."""
    logs = tmp_path_factory.mktemp('namespaces')
    domain = domain_id('namespaces')
    procs = []
    for ns, f_d in F_D.items():
        remap = ['-r', f'__ns:={ns}']
        procs.append(NodeProcess(SIM_MODULE, logs / f'sim{ns[-1]}.log', domain, remap))
        procs.append(NodeProcess(CONTROLLER_MODULE, logs / f'controller{ns[-1]}.log', domain,
                                 [*remap, '-p', f'f_d:={f_d}']))
    spun = Spun(domain)
    try:
        forces = {ns: ForceLog(spun, name='namespace_watcher', namespace=ns) for ns in F_D}
        for p in procs:
            p.start()
        yield forces, procs
    finally:
        for p in procs:
            p.stop()
        spun.close()


def _endpoints(node: Node, topic: str, publishers: bool) -> set[str]:
    info = (node.get_publishers_info_by_topic(topic) if publishers
            else node.get_subscriptions_info_by_topic(topic))
    return {f"{i.node_namespace.rstrip('/')}/{i.node_name}" for i in info}


def test_namespace_moves_every_topic(two_arms):
    forces, procs = two_arms
    w = forces['/arm1'].node  # the graph is the same from any node
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
    forces, procs = two_arms
    for ns, f_d in F_D.items():
        def within(log=forces[ns], f_d=f_d) -> bool:
            f = log.recent(300)
            return f.size == 300 and bool(np.all(np.abs(f - f_d) < 0.1))
        wait_for(within, f'{ns}: 3 s of true force within 0.1 N of {f_d} N', alive=procs)
    for ns, log in forces.items():  # each arm's own statuses, by the node's full name
        assert_clean_run(log.fresh_diag(f'{ns}/hybrid_force_controller', procs),
                         log.fresh_diag(f'{ns}/sim', procs),
                         run=log.statuses(f'{ns}/hybrid_force_controller'))
