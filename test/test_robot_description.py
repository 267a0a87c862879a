"""
Where the robot model comes from.

The robot_description topic, a .xacro path, the bundled arm only when asked, and a clear
reason when nothing was given.
"""
from __future__ import annotations

from helpers.ros import CONTROLLER_MODULE, domain_id, NodeProcess, ROOT, Spun, wait_for
from helpers.watch import ForceLog
from hybrid_force_controller.core.config.params import ParameterValidationError
from hybrid_force_controller.core.model.robot_model import default_urdf_path
from hybrid_force_controller.ros.common.qos import DESCRIPTION_QOS
from hybrid_force_controller.ros.controller.controller_node import ControllerNode
import pytest
from rclpy.parameter import Parameter
from std_msgs.msg import String


PANDA = ROOT / 'config' / 'panda_params.yaml'
WAITING = "waiting for the URDF on '/r1/robot_description'"


def test_waits_for_the_robot_description_topic_then_starts(tmp_path):
    domain = domain_id('robot_description')
    ctrl = NodeProcess(CONTROLLER_MODULE, tmp_path / 'controller.log', domain,
                       ['-r', '__ns:=/r1', '-p', 'use_bundled_model:=false'])
    with Spun(domain) as spun, ctrl:
        node = spun.node('description_publisher')
        log = ForceLog(spun)  # the controller's /diagnostics
        wait_for(lambda: WAITING in ctrl.log_since(), 'the waiting log line', alive=[ctrl])
        state = log.diag('/r1/hybrid_force_controller').get('lifecycle_state', 'unconfigured')
        assert state == 'unconfigured', state
        pub = node.create_publisher(String, '/r1/robot_description', DESCRIPTION_QOS)
        pub.publish(String(data=default_urdf_path().read_text()))
        wait_for(lambda: log.diag('/r1/hybrid_force_controller').get('lifecycle_state')
                 == 'active', 'the controller active on the topic URDF', alive=[ctrl])
    assert 'robot_description received' in ctrl.log_since()


def test_xacro_path_is_expanded(tmp_path):
    urdf = default_urdf_path().read_text()
    xacro_text = urdf.replace('<robot ', '<robot xmlns:xacro="http://www.ros.org/wiki/xacro" ', 1)
    xacro_text = xacro_text.replace('<mass value="1.3"/>', '<mass value="${m1}"/>')
    xacro_text = xacro_text.replace('<link ', '<xacro:property name="m1" value="2.6"/>\n  <link ',
                                    1)
    assert '${m1}' in xacro_text
    path = tmp_path / 'arm.urdf.xacro'
    path.write_text(xacro_text)
    with Spun(domain_id('robot_description')) as spun:
        node = spun.add(ControllerNode(context=spun.context, parameter_overrides=[
            Parameter('robot_description', value=str(path))]))
        assert node.state_label == 'active'
        assert node.model.theta_nominal[0] == pytest.approx(2.6)  # the xacro property


def test_panda_params_alone_say_that_robot_description_is_missing(tmp_path):
    ctrl = NodeProcess(CONTROLLER_MODULE, tmp_path / 'controller.log',
                       domain_id('robot_description'), params_file=PANDA)
    with ctrl:
        wait_for(lambda: "waiting for the URDF on '/robot_description'" in ctrl.log_since(),
                 'the reason in the log', alive=[ctrl])
        assert 'not in the URDF' not in ctrl.log_since()


def test_bundled_arm_with_other_joints_names_the_cause():
    with Spun(domain_id('robot_description'),
              args=['--ros-args', '--params-file', str(PANDA)]) as spun:
        with pytest.raises(ParameterValidationError, match='use_bundled_model is true'):
            ControllerNode(context=spun.context, parameter_overrides=[
                Parameter('use_bundled_model', value=True)])
