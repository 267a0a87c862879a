"""
The tool's mass, centre of mass and the sensor's biases from still poses (tool_identification.py).

Synthetic poses of a wrist sensor (seeded): the fit returns what made the readings, exactly
without noise and within the noise's reach with it; its residuals grow when one pose was not
still (a pull the model has no term for); poses that see gravity from too few sides, too few
poses and NaN are refused with the reason.
"""
from __future__ import annotations

from hybrid_force_controller.core.model.tool_gravity import tool_weight_S
from hybrid_force_controller.core.model.tool_identification import (
    IdentificationError, identify_tool)
import numpy as np
import pytest

G_W = np.array([0.0, 0.0, -9.81])
MASS, COM = 0.8, np.array([0.01, -0.02, 0.06])
B_F, B_T = np.array([0.8, -2.5, 0.4]), np.array([0.05, 0.02, -0.03])


def _rot(axis, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    K = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


POSES = np.array([np.eye(3), _rot([1, 0, 0], 0.8), _rot([0, 1, 0], -0.8), _rot([1, 1, 0], 1.6),
                  _rot([0, 1, 0], 2.5), _rot([1, 0, 1], -1.2)])


def _readings(R, noise: float = 0.0, seed: int = 3):
    rng = np.random.default_rng(seed)
    F, T = [], []
    for R_i in R:
        F_g, tau_g = tool_weight_S(MASS, COM, R_i, G_W)
        F.append(F_g + B_F + rng.normal(0.0, noise, 3))
        T.append(tau_g + B_T + rng.normal(0.0, noise * 0.01, 3))
    return np.array(F), np.array(T)


def test_the_fit_returns_the_tool_and_the_biases_that_made_the_readings():
    fit = identify_tool(POSES, *_readings(POSES), G_W)
    assert fit.tool_mass == pytest.approx(MASS, abs=1e-12)
    np.testing.assert_allclose(fit.tool_com, COM, atol=1e-12)
    np.testing.assert_allclose(fit.force_bias, B_F, atol=1e-12)
    np.testing.assert_allclose(fit.torque_bias, B_T, atol=1e-12)
    assert fit.force_residual_n < 1e-12 and fit.torque_residual_n_m < 1e-12
    assert fit.poses == len(POSES)


def test_with_a_sensors_noise_the_fit_is_within_its_reach():
    fit = identify_tool(POSES, *_readings(POSES, noise=0.02), G_W)  # 20 mN, 0.2 mN m
    assert fit.tool_mass == pytest.approx(MASS, abs=0.01)  # 20 mN / 9.81 ~ 2 g a pose
    np.testing.assert_allclose(fit.tool_com, COM, atol=2e-3)
    assert 0.005 < fit.force_residual_n < 0.05


def test_a_pose_that_was_not_still_shows_in_the_residual():
    F, T = _readings(POSES)
    F[3] += [0.0, 0.0, 1.5]  # a cable pulled 1.5 N in one pose
    T[3] += [0.1, 0.0, 0.0]
    fit = identify_tool(POSES, F, T, G_W)
    assert fit.force_residual_n > 0.3 and fit.torque_residual_n_m > 0.02


@pytest.mark.parametrize('poses, words', [
    (POSES[:2], 'at least 3 still poses'),
    (np.array([np.eye(3), _rot([0, 0, 1], 1.0), _rot([0, 0, 1], 2.0)]), 'too few sides'),
])
def test_poses_that_cannot_determine_the_tool_are_refused(poses, words):
    with pytest.raises(IdentificationError, match=words):
        identify_tool(poses, *_readings(poses), G_W)


def test_nan_and_mismatched_shapes_are_refused():
    F, T = _readings(POSES)
    F[1, 0] = np.nan
    with pytest.raises(IdentificationError, match='NaN'):
        identify_tool(POSES, F, T, G_W)
    with pytest.raises(IdentificationError, match='need n rotations'):
        identify_tool(POSES, F[:4], T, G_W)


# ------------------------------------------------------------------ from a bag (identify_tool)
PANDA_JOINTS = [f'panda_joint{k}' for k in range(1, 8)]
PANDA_POSES = np.array([[0.0, -0.3, 0.0, -2.0, 0.0, 1.8, 0.8],
                        [0.0, -0.3, 0.0, -2.0, 0.9, 1.8, 0.8],
                        [0.0, -0.3, 0.0, -2.0, 0.0, 1.0, 0.8],
                        [0.0, -0.3, 0.0, -2.0, -0.8, 2.4, -0.5]])
FRAME = 'panda_hand_tcp'


def _write_bag(path, model, seed: int = 5) -> None:
    """Still 1 s at each pose (a ramp of 0.5 s between), joint states and wrenches at 200 Hz."""
    from hybrid_force_controller.tools.bag_io import BagWriter, TYPESTORE
    T = TYPESTORE.types
    rng = np.random.default_rng(seed)
    g_W = model.model.gravity.linear
    topics = [('/joint_states', 'sensor_msgs/msg/JointState'),
              ('/force_torque_sensor_broadcaster/wrench', 'geometry_msgs/msg/WrenchStamped')]
    times = np.arange(0.0, 1.5 * len(PANDA_POSES), 0.005)
    with BagWriter(path, topics) as bag:
        for t in times:
            k, s = int(t // 1.5), (t % 1.5 - 1.0) / 0.5  # still, then a ramp to the next
            nxt = PANDA_POSES[min(k + 1, len(PANDA_POSES) - 1)]
            q = PANDA_POSES[k] + max(s, 0.0) * (nxt - PANDA_POSES[k])
            stamp = T['builtin_interfaces/msg/Time'](sec=int(t) + 100, nanosec=int(t % 1 * 1e9))
            header = T['std_msgs/msg/Header'](stamp=stamp, frame_id=FRAME)
            js = T['sensor_msgs/msg/JointState'](header=header, name=PANDA_JOINTS, position=q,
                                                 velocity=np.zeros(7), effort=np.zeros(7))
            F_g, tau_g = tool_weight_S(MASS, COM, model.frame_rotation(q, FRAME), g_W)
            F, tau = F_g + B_F + rng.normal(0, 0.01, 3), tau_g + B_T + rng.normal(0, 1e-4, 3)
            V = T['geometry_msgs/msg/Vector3']
            wrench = T['geometry_msgs/msg/Wrench'](force=V(*F), torque=V(*tau))
            ns = int((t + 100) * 1e9)
            bag.write_msg('/joint_states', ns, js)
            bag.write_msg(topics[1][0], ns, T['geometry_msgs/msg/WrenchStamped'](
                header=header, wrench=wrench))


def test_identify_tool_finds_the_still_poses_of_a_bag_and_prints_the_parameters(tmp_path, capsys):
    from hybrid_force_controller.core.model.robot_model import RobotModel
    from hybrid_force_controller.core.offline.arm7 import panda_urdf_path
    from hybrid_force_controller.tools.identify_tool import identify_from_bag, main
    model = RobotModel.from_urdf(str(panda_urdf_path()), joints=PANDA_JOINTS,
                                 end_effector_link=FRAME, gravity_root=(0.0, 0.0, -9.81))
    _write_bag(tmp_path / 'bag', model)
    fit, frame = identify_from_bag(tmp_path / 'bag', model, '/joint_states',
                                   '/force_torque_sensor_broadcaster/wrench')
    assert frame == FRAME and fit.poses == len(PANDA_POSES)  # the ramps are not still
    assert fit.tool_mass == pytest.approx(MASS, abs=0.005)
    np.testing.assert_allclose(fit.tool_com, COM, atol=2e-3)
    np.testing.assert_allclose(fit.force_bias, B_F, atol=0.01)
    assert fit.force_residual_n < 0.01
    argv = [str(tmp_path / 'bag'), '--urdf', str(panda_urdf_path()), '--gravity', '0', '0',
            '-9.81', '--joints', *PANDA_JOINTS]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert '4 still poses' in out and f'tool_mass: {fit.tool_mass:.6g}' in out
    assert main([str(tmp_path / 'bag'), '--urdf', str(panda_urdf_path()), '--joints',
                 *PANDA_JOINTS, '--wrench', '/nowhere']) == 1
    assert 'topic /nowhere is not in bag' in capsys.readouterr().err
