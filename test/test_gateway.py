"""
The cell domain and its gateway (ros/common/cell.py, ros/common/gateway.py; issue 30).

* ``cell_domains`` reads ``ROS_DOMAIN_ID`` and ``HFC_CELL_DOMAIN_ID`` and refuses what cannot
  work, saying why;
* the sim and the controller started as a user starts them (no variable set) run on the cell
  domain, and on the user's domain the gateway shows their nodes, takes ``ros2 param set``
  (accepted and refused sets), mirrors the efforts and the telemetry, and feeds ``~/``
  topics in; the cell's own writers never appear on the user's domain;
* a user's ``joint_states`` on the user's domain never reaches the loop;
* default-profile joiners that subscribe to every topic (as ``ros2 bag record -a``), one a
  second, cause no command timeout at the plant (the sim's counter, over DDS);
* the run is clean: no callback error, no safe mode.
"""
from __future__ import annotations

import math
import subprocess
import sys

from helpers.figures import current_test, report_figure
from helpers.ros import domain_id, ROOT, Spun, wait_for, wait_future
from helpers.watch import assert_clean_run, RealTimeRig
from hybrid_force_controller.ros.common.cell import cell_domains, CELL_VAR
from hybrid_force_controller.ros.common.gateway import fed_into_cell, Gateway
from hybrid_force_controller.ros.lab.join_stall import PROBES
from hybrid_force_controller.ros.programs.launch import PROFILE_VAR
import pytest
import rclpy
from rclpy.context import Context
from std_msgs.msg import String

GATEWAY = '_hfc_gateway'
UNKNOWN = '_NODE_NAME_UNKNOWN_'  # rcl's name of a node not discovered yet
ASKS, ASK_TIMEOUT_S = 3, 20.0  # a parameter set asked again if unanswered this long


@pytest.mark.parametrize('env, public, cell', [
    ({}, 0, 100), ({'ROS_DOMAIN_ID': '42'}, 42, 142), ({'ROS_DOMAIN_ID': '150'}, 150, 50),
    ({'ROS_DOMAIN_ID': '7', CELL_VAR: '200'}, 7, 200), ({CELL_VAR: ' AUTO '}, 0, 100),
    ({'ROS_DOMAIN_ID': '5', CELL_VAR: 'off'}, 5, None)])
def test_cell_domains(env, public, cell):
    domains = cell_domains(env)
    assert (domains.public, domains.cell) == (public, cell)
    assert domains.node_domain == (public if cell is None else cell)
    assert domains.isolated is (cell is not None)


@pytest.mark.parametrize('env, says', [
    ({CELL_VAR: '300'}, '0-232'), ({CELL_VAR: 'x'}, 'must be a number'),
    ({'ROS_DOMAIN_ID': '9', CELL_VAR: '9'}, 'must differ'),
    ({'ROS_DOMAIN_ID': 'nine'}, 'ROS_DOMAIN_ID')])
def test_cell_domains_refused(env, says):
    with pytest.raises(ValueError, match=says):
        cell_domains(env)


@pytest.mark.parametrize('topic, fed', [
    ('/cell/arm1/hybrid_force_controller/path', True),
    ('/hybrid_force_controller/target_wrench', True),
    ('/robot_description', True),
    ('/joint_states', False),
    ('/cell/arm1/joint_states', False),
    ('/effort_controller/commands', False),
    ('/arm2/effort_controller/commands', False),
    ('/force_torque_sensor_broadcaster/wrench', False),
    ('/clock', False),
    ('/sim/contact_wrench', False),  # published in the cell once: plant_topics
])
def test_the_loops_topics_are_never_fed_into_the_cell(topic, fed):
    """Even before the cell's writer of a loop topic is discovered (its reader seen first)."""
    assert fed_into_cell(topic, {'/sim/contact_wrench'}) is fed


@pytest.fixture(scope='module')
def rig(tmp_path_factory):
    """Run the paper's cell in real time, watched from the user's domain through the gateway."""
    rig = RealTimeRig(tmp_path_factory.mktemp('gateway'), domain_id('gateway'), isolated=True)
    try:
        yield rig.start()
    finally:
        rig.close()


def _set(rig, **values):
    from rclpy.parameter import Parameter
    params = [Parameter(k, value=v) for k, v in values.items()]
    # a request sent before the client has matched the gateway's service is lost, not queued:
    # the services' endpoints are discovered after the node's name (seen on one CPU)
    wait_for(lambda: rig.params.services_are_ready(), "the gateway's parameter services",
             alive=rig.procs)
    # ready means the request's reader matched; the answer's writer may match later (one CPU:
    # the first request went unanswered): a set is idempotent, so it is asked again
    for _ in range(ASKS - 1):
        future = rig.params.set_parameters(params)
        try:
            return wait_future(future, ASK_TIMEOUT_S).results
        except AssertionError:
            print('the gateway did not answer a parameter set: asking again')
    return wait_future(rig.params.set_parameters(params)).results


def test_the_gateway_shows_the_cell_on_the_users_domain(rig):
    node = rig.log.node
    wait_for(lambda: {('hybrid_force_controller', '/'), ('sim', '/')}
             <= set(node.get_node_names_and_namespaces()), 'the cell nodes on the user domain')
    # the endpoints are discovered after the nodes' names (seconds apart on one CPU), and an
    # endpoint may be seen before its node's name (rcl's UNKNOWN: a clean-clone run failed so)

    def named_writers() -> list:
        found = node.get_publishers_info_by_topic('/effort_controller/commands')
        return found if found and all(w.node_name != UNKNOWN for w in found) else []
    wait_for(named_writers, "the gateway's mirror of the efforts, named", alive=rig.procs)
    writers = node.get_publishers_info_by_topic('/effort_controller/commands')
    assert {w.node_name for w in writers} == {GATEWAY}, writers
    assert not any(i.node_name == GATEWAY
                   for i in node.get_subscriptions_info_by_topic('/joint_states'))
    with Spun(cell_domains(rig.sim.env).cell) as cell:
        probe = cell.node('cell_probe')
        wait_for(lambda: ('_hybrid_force_controller_rt', '/')
                 in probe.get_node_names_and_namespaces(), 'the loop node on the cell domain')
        wait_for(lambda: probe.get_publishers_info_by_topic('/effort_controller/commands'),
                 'the loop node writing the efforts on the cell domain', alive=rig.procs)
        # a writer's node name comes with its participant's data, which may come later (one
        # CPU: '_NODE_NAME_UNKNOWN_' beside the loop node's): wait until every name is known
        wait_for(lambda: UNKNOWN not in {w.node_name for w in probe.get_publishers_info_by_topic(
            '/effort_controller/commands')}, "the efforts' writers named", alive=rig.procs)
        cell_writers = probe.get_publishers_info_by_topic('/effort_controller/commands')
        assert {w.node_name for w in cell_writers} == {'_hybrid_force_controller_rt'}


def test_parameters_through_the_gateway(rig):
    ok = _set(rig, f_d=1.5)
    assert ok[0].successful, ok[0].reason
    assert wait_future(rig.params.get_parameters(['f_d'])).values[0].double_value == 1.5
    refused = _set(rig, lambda1=10.0)
    assert not refused[0].successful and 'eq. (29)' in refused[0].reason, refused[0].reason
    assert wait_future(rig.params.get_parameters(['lambda1'])).values[0].double_value == 40.0
    ok = _set(rig, f_d=1.0)
    assert ok[0].successful, ok[0].reason


def test_the_efforts_and_the_telemetry_are_mirrored(rig):
    from geometry_msgs.msg import PointStamped
    from std_msgs.msg import Float64MultiArray
    node = rig.log.node
    efforts, xs = [], []
    subs = [node.create_subscription(Float64MultiArray, '/effort_controller/commands',
                                     efforts.append, 100),
            node.create_subscription(PointStamped, '/hybrid_force_controller/x', xs.append, 100)]
    try:
        wait_for(lambda: len(efforts) >= 200 and len(xs) >= 20, 'mirrored efforts and ~/x',
                 alive=rig.procs)
    finally:
        for sub in subs:
            node.destroy_subscription(sub)
    assert all(len(m.data) == 2 and all(math.isfinite(v) for v in m.data) for m in efforts[:200])


def test_a_users_joint_states_never_reach_the_loop(rig):
    from sensor_msgs.msg import JointState
    node = rig.log.node
    key = 'callback_errors_joint_states'
    before = rig.log.fresh_diag('hybrid_force_controller', alive=rig.procs)
    pub = node.create_publisher(JointState, '/joint_states', 10)
    bad = JointState(name=['joint1', 'joint2'], position=[math.nan] * 2, velocity=[0.0] * 2)
    sent = []

    def send() -> None:  # NaN joint states at 100 Hz, stamped now
        bad.header.stamp = node.get_clock().now().to_msg()
        pub.publish(bad)
        sent.append(1)
    timer = node.create_timer(0.01, send)
    try:
        wait_for(lambda: len(sent) >= 100, '1 s of NaN joint states on the user domain',
                 alive=rig.procs)
        readers = pub.get_subscription_count()  # the gateway feeds no cell-published topic
    finally:
        node.destroy_timer(timer)
        node.destroy_publisher(pub)
    after = rig.log.fresh_diag('hybrid_force_controller', alive=rig.procs)
    assert readers == 0
    assert after['mode'] == 'running', after
    assert after.get(key, 0) == before.get(key, 0), after


def test_default_profile_joiners_cause_no_command_timeout(rig):
    env = {k: v for k, v in rig.sim.env.items() if k != PROFILE_VAR}
    before = rig.log.fresh_diag('sim', alive=rig.procs)
    procs = []
    try:
        for _ in range(5):  # one joiner a second: the sim reports once a second
            procs.append(subprocess.Popen([sys.executable, '-c', PROBES['all']], env=env,
                                          cwd=ROOT, stdout=subprocess.DEVNULL,
                                          stderr=subprocess.DEVNULL))
            rig.log.fresh_diag('sim', alive=rig.procs)
        for p in procs:
            p.wait(60)
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
                p.wait()
    after = rig.log.fresh_diag('sim', alive=rig.procs)
    report_figure(current_test(),
                  command_timeouts=after['command_timeouts'] - before['command_timeouts'],
                  commands=after['commands'] - before['commands'],
                  command_gap_max_ms=after.get('command_gap_max_ms'))
    assert [p.returncode for p in procs] == [0] * 5
    assert after['command_timeouts'] == before['command_timeouts'], (before, after)
    assert after['commands'] > before['commands']


def test_the_run_is_clean(rig):
    """Last: a user's sets, NaN joint states and joiners on the user domain left no error."""
    assert_clean_run(rig.log.fresh_diag('hybrid_force_controller', alive=rig.procs),
                     rig.log.fresh_diag('sim', alive=rig.procs),
                     run=rig.log.statuses('hybrid_force_controller'))
    for proc in (rig.sim, rig.ctrl):  # the gateway writes to the log of the node that began it
        text = proc.log_path.read_text(errors='replace')
        assert 'Fatal Python error' not in text, f'a crash in {proc.log_path.name}'


def test_the_mirrors_carry_no_qos_event_handlers():
    """
    A mirror's reader and writer have no QoS event handler (gateway NO_EVENTS_*).

    The Jazzy EventsExecutor segfaulted in the gateway as its mirrors started (21 of 45 demo
    runs; a Python call without the GIL inside spin_once), and never without the handlers
    (0 of 12). A gateway in this process mirrors a topic of a cell node here to a reader.
    """
    domains = cell_domains({'ROS_DOMAIN_ID': str(domain_id('gateway_mirror'))})
    public, cell = domains.public, domains.cell
    gateway = Gateway(domains)
    ctx_cell, ctx_user = Context(), Context()
    rclpy.init(context=ctx_cell, domain_id=cell)
    rclpy.init(context=ctx_user, domain_id=public)
    try:
        writer = rclpy.create_node('writer', context=ctx_cell)
        writer.create_publisher(String, 'mirrored', 10)
        reader, watching = rclpy.create_node('reader', context=ctx_user), []

        def mirrored() -> bool:
            gateway.scan()
            while gateway.cell_ops:
                gateway.cell_ops.popleft()()
            entry = gateway.out.get('/mirrored')
            if entry is not None and not watching:  # watched once it is mirrored
                watching.append(reader.create_subscription(String, 'mirrored', len, 10))
            return entry is not None and entry[1] is not None
        wait_for(mirrored, 'the gateway mirroring /mirrored to a reader', 30.0)
        publisher, subscription, _ = gateway.out['/mirrored']
        assert publisher.event_handlers == [] and subscription.event_handlers == []
    finally:
        gateway.close()
        rclpy.try_shutdown(context=ctx_cell)
        rclpy.try_shutdown(context=ctx_user)
