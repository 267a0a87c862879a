"""
Tool gravity compensation (``tool_mass``, ``tool_com``; core/model/tool_gravity.py), offline.

With ``tool_mass = 0`` the controller is exactly today's (bitwise-identical efforts, whatever
``tool_com``); with a tool whose weight the wrist sensor reads, ``tool_mass`` removes it and the
efforts are those of the run without a tool; without it the weight is taken for contact force.
"""
from __future__ import annotations

from hybrid_force_controller.core.config.params import build_params, ParameterValidationError
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.model.tool_gravity import tool_weight_S, tool_weight_W
from hybrid_force_controller.core.offline.scenario import run_scenario, ScenarioConfig
import numpy as np
import pytest

MASS = 0.2


def _with_weight(model):
    """Input hook: the sensor also reads a 0.2 kg tool's weight (in the end-effector frame)."""
    g_W = model.model.gravity.linear

    def hook(t, msg):
        q, qdot, F_S = msg
        R_W_ee = model.kinematics(q, qdot).R_W_ee
        return q, qdot, F_S + tool_weight_S(MASS, np.zeros(3), R_W_ee, g_W)[0]
    return hook


def _run(**kwargs):
    return run_scenario(ScenarioConfig(duration=3.0, delay_steps=1, **kwargs))


def test_zero_tool_mass_leaves_the_efforts_bitwise_identical():
    base = _run()
    same = _run(overrides={'tool_mass': 0.0, 'tool_com': [0.01, 0.02, 0.03]})
    assert np.array_equal(base.tau, same.tau)


def test_tool_mass_removes_the_weight_the_sensor_reads():
    model = RobotModel.from_urdf()
    base = _run()
    compensated = _run(overrides={'tool_mass': MASS}, input_hook=_with_weight(model))
    np.testing.assert_allclose(compensated.tau, base.tau, rtol=0.0, atol=1e-9)
    raw = _run(input_hook=_with_weight(model))  # uncompensated: the weight looks like force
    after = raw.t >= 2.0
    n_W = raw.n_W
    f_err = float(np.mean(raw.f_true_W[after] @ n_W) - 1.0)
    # gravity (-y) is along n here: the sensed weight hides m g of force, the arm presses m g more
    assert f_err == pytest.approx(MASS * 9.81, rel=0.05)


def test_weight_in_the_sensor_frame_and_its_torque():
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    g_W = np.array([0.0, 0.0, -9.81])
    F, T = tool_weight_S(0.5, np.array([0.1, 0.0, 0.0]), R, g_W)
    np.testing.assert_allclose(F, [0.0, 0.0, -4.905])
    np.testing.assert_allclose(T, np.cross([0.1, 0.0, 0.0], F))
    assert tool_weight_W(0.0, g_W) is None
    np.testing.assert_allclose(tool_weight_W(0.5, g_W), 0.5 * g_W)


@pytest.mark.parametrize('values, words', [({'tool_mass': -0.1}, 'tool_mass'),
                                           ({'tool_com': [0.0, 0.1]}, 'tool_com')])
def test_bad_tool_parameters_are_refused(values, words):
    with pytest.raises(ParameterValidationError, match=words):
        build_params(RobotModel.from_urdf(), values)
