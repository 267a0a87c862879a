"""
Building ``hybrid_force_controller.core.model.robot_model.RobotModel`` from a URDF, and its errors.

A redundant planar arm (accepted; the square-Jacobian terms (35)-(37) refuse it), too few
joints, a base link that moves or does not exist, an unknown end-effector link, a missing file;
a URDF given as an XML string gives the same model as the file.
"""
from __future__ import annotations

from pathlib import Path

from hybrid_force_controller.core.model.robot_model import (default_urdf_path, ModelError,
                                                            RobotModel)
import numpy as np
import pytest

PLANAR_3LINK_URDF = Path(__file__).resolve().parent / 'three_link_planar.urdf'


def test_planar_three_link_is_a_redundant_planar_arm():
    """3 joints for a 2-D planar task space: accepted as redundant; (35)-(37) refuse it."""
    arm3 = RobotModel.from_urdf(PLANAR_3LINK_URDF)
    assert arm3.task_axes == (0, 1) and arm3.n == 3 and arm3.redundant
    with pytest.raises(ModelError, match='square Jacobian'):
        arm3.task_terms(np.array([0.3, 0.4, 0.5]), np.zeros(3))


def test_fewer_joints_than_the_task_needs_is_rejected():
    """One revolute joint moves the tip in a plane (2-D task): ModelError 'fewer joints'."""
    xml = default_urdf_path().read_text()
    with pytest.raises(ModelError, match='fewer joints'):
        RobotModel.from_urdf(xml, joints=['joint1'])


def test_base_link_must_be_fixed_and_known():
    xml = default_urdf_path().read_text()
    with pytest.raises(ModelError, match='link1'):
        RobotModel.from_urdf(xml, base_link='link1', gravity_root=(0, -9.81, 0))
    with pytest.raises(ModelError, match='nowhere'):
        RobotModel.from_urdf(xml, base_link='nowhere')


def test_unknown_end_effector_link_is_rejected():
    """A URDF string with an unknown end-effector link: ModelError naming the link."""
    xml = default_urdf_path().read_text()
    with pytest.raises(ModelError, match='no_such_link'):
        RobotModel.from_urdf(xml, end_effector_link='no_such_link')


@pytest.mark.parametrize('as_path', [False, True])
def test_missing_urdf_file_is_rejected(tmp_path, as_path):
    """A URDF path that does not exist: ModelError (str or Path)."""
    missing = tmp_path / 'missing.urdf'
    with pytest.raises(ModelError, match='not found'):
        RobotModel.from_urdf(missing if as_path else str(missing))


def test_urdf_string_loads_like_file():
    """The bundled URDF given as an XML string gives the same model as the file."""
    from_file = RobotModel.from_urdf()
    from_xml = RobotModel.from_urdf(default_urdf_path().read_text())
    q, qdot = np.array([0.657, 0.913]), np.array([0.3, -0.2])
    for a, b in zip(from_file.joint_terms(q, qdot), from_xml.joint_terms(q, qdot)):
        np.testing.assert_array_equal(a, b)
