"""
QoS of the controller's inputs: best-effort sensor publishers must reach it.

This process plays the robot: it publishes ``joint_states`` and the F/T ``wrench`` with
``qos_profile_sensor_data`` (BEST_EFFORT, as many F/T drivers do). With the default
``sensor_qos`` (best_effort) the controller runs and commands; with ``sensor_qos:=reliable``
a best-effort publisher cannot match, and the controller keeps waiting (the parameter is
what makes the difference). The command topic is RELIABLE/KEEP_LAST 1.
"""
from __future__ import annotations

import threading

from geometry_msgs.msg import WrenchStamped
from helpers.ros import CONTROLLER_MODULE, domain_id, NodeProcess, Spun, wait_for
from helpers.watch import assert_clean_run, ForceLog
import pytest
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray


NAME = 'hybrid_force_controller'


class _Robot(Node):
    """Publishes a still arm (best effort) at 200 Hz; counts the commands."""

    def __init__(self, context) -> None:
        super().__init__('best_effort_robot', context=context)
        self.lock = threading.Lock()
        self.commands = 0
        self.sent = 0
        self.pub_js = self.create_publisher(JointState, 'joint_states', qos_profile_sensor_data)
        self.pub_ft = self.create_publisher(
            WrenchStamped, 'force_torque_sensor_broadcaster/wrench', qos_profile_sensor_data)
        self.create_subscription(Float64MultiArray, 'effort_controller/commands',
                                 self._on_command, QoSProfile(depth=100))
        self.create_timer(0.005, self._publish)

    def _publish(self) -> None:
        stamp = self.get_clock().now().to_msg()
        js = JointState(name=['joint1', 'joint2'], position=[0.657, 0.913], velocity=[0.0, 0.0])
        ft = WrenchStamped()
        ft.header.frame_id = 'tool0'
        js.header.stamp = ft.header.stamp = stamp
        self.pub_ft.publish(ft)
        self.pub_js.publish(js)
        with self.lock:
            self.sent += 1

    def _on_command(self, _msg) -> None:
        with self.lock:
            self.commands += 1


@pytest.fixture
def robot():
    with Spun(domain_id('qos')) as spun:
        robot = spun.add(_Robot(spun.context))
        robot.log = ForceLog(spun)  # the controller's /diagnostics
        yield robot


def test_best_effort_sensor_publishers_reach_the_controller(robot, tmp_path):
    assert robot.pub_js.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT
    with NodeProcess(CONTROLLER_MODULE, tmp_path / 'controller.log', domain_id('qos')) as ctrl:
        # a still arm with no force: the controller commands an approach (not 'waiting')
        wait_for(lambda: robot.log.diag(NAME).get('mode') in ('approach', 'no_surface', 'running')
                 and robot.commands > 100, 'the controller commanding on best-effort inputs',
                 alive=[ctrl])
        assert robot.pub_js.get_subscription_count() == 1
        assert robot.pub_ft.get_subscription_count() == 1
        assert_clean_run(robot.log.fresh_diag(NAME, [ctrl]), run=robot.log.statuses(NAME))


def test_reliable_inputs_do_not_match_best_effort_publishers(robot, tmp_path):
    args = ['-p', 'sensor_qos:=reliable']
    ctrl = NodeProcess(CONTROLLER_MODULE, tmp_path / 'controller.log', domain_id('qos'), args)
    with ctrl:
        wait_for(lambda: robot.log.diag(NAME).get('lifecycle_state') == 'active',
                 'the controller active', alive=[ctrl])
        sent = robot.sent
        wait_for(lambda: robot.sent >= sent + 200, '1 s more of best-effort states', alive=[ctrl])
        assert robot.log.diag(NAME).get('mode') in (None, 'waiting'), robot.log.diag(NAME)
        assert robot.commands == 0
        assert robot.pub_js.get_subscription_count() == 0  # incompatible QoS: no match
