"""
The delay margin (margin.py) against the loop it predicts, and its use.

The margin is a linear analysis of each task axis with a delayed control force (the
module docstring); the loop engine runs the nonlinear arm with exactly ``d`` periods of
sensor-to-actuation delay (lockstep timing), so the prediction can be checked: below the
margin the loop holds, above it the force oscillates off the surface. No ROS.
"""
from __future__ import annotations

import dataclasses
import math

from hybrid_force_controller.core.config.params import build_params, ParameterValidationError
from hybrid_force_controller.core.law.margin import axis_margin, delay_margin
from hybrid_force_controller.core.offline.scenario import PAPER_Q0, run_scenario, ScenarioConfig
from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime
import numpy as np
import pytest


Q0 = np.array(PAPER_Q0)


def _holds(delay_steps: int, overrides: dict) -> bool:
    """
    4 s on the stiffest surface (k_max) with ``delay_steps`` periods of delay.

    The force stays within 0.2 N of f_d after 2 s.
    """
    r = run_scenario(ScenarioConfig(k=6000.0, delay_steps=delay_steps, duration=4.0,
                                    overrides=overrides))
    f = (r.f_true_W @ r.n_W)[r.t > 2.0]
    return bool(np.all(np.abs(f - 1.0) < 0.2))


@pytest.mark.parametrize('overrides', [{}, {'k_d': 200.0, 'k_a': 6000.0}, {'k_d': 100.0}],
                         ids=['defaults', 'old-defaults', 'k_d-100'])
def test_predicted_margin_separates_stable_from_unstable_delays(model, overrides):
    margin_ms = delay_margin(model, build_params(model, overrides).law, Q0, 200.0) * 1e3
    below, above = math.floor(margin_ms) - 1, math.ceil(margin_ms) + 2
    assert _holds(below, overrides), f'unstable at {below} ms, margin {margin_ms:.2f} ms'
    assert not _holds(above, overrides), f'stable at {above} ms, margin {margin_ms:.2f} ms'


def test_default_gains_keep_a_10_ms_margin_across_the_workspace(model):
    """The documented design point: >= 10 ms of loop delay at k_max (docs/design.md)."""
    law = build_params(model).law
    for q in (Q0, (0.3, 1.4), (0.9, 0.6), (0.5, 1.2)):
        assert delay_margin(model, law, np.array(q), 200.0) >= 0.010, q


def test_lower_k_d_and_slower_adaptation_give_more_margin(model):
    def margin(**kw):
        return delay_margin(model, build_params(model, kw).law, Q0, 200.0)
    assert margin(k_d=30.0) > margin() > margin(k_d=120.0)
    assert margin() > margin(k_a=3000.0) > margin(k_a=6000.0)


def test_an_axis_unstable_without_delay_has_no_margin(model):
    """Control: a negative K_D makes the tangential axis unstable at zero delay."""
    law = build_params(model).law
    bad = dataclasses.replace(law, k_d=-200.0)
    assert axis_margin(bad, 1.0, 0.0) == 0.0
    assert axis_margin(law, 1.0, 0.0) > 0.0  # K_I = 0: the pole at s = 0 cancels


def test_runtime_refuses_gains_without_margin_and_says_why(model):
    rt = ControllerRuntime(model, build_params(model))
    rt.on_joint_state(list(model.joint_names), Q0, np.zeros(2), 0.0)
    with pytest.raises(ParameterValidationError) as exc:
        rt.validate({'k_d': 200.0, 'k_a': 6000.0})
    msg = str(exc.value)
    # 4.40 ms: the worst also over the k_s the stiffness estimate may command (4.5 ms
    # at the configured k_s alone)
    assert 'delay margin' in msg and '4.40' in msg and '5.00 ms' in msg, msg
    rt.validate({'k_d': 200.0, 'k_a': 6000.0, 'min_delay_margin': 0.004})  # accepted
    rt.validate({'k_d': 200.0, 'k_a': 6000.0, 'min_delay_margin': 0.0})    # check off


def test_no_margin_check_before_the_first_state(model):
    rt = ControllerRuntime(model, build_params(model))
    assert rt.delay_margin() == math.inf
    rt.validate({'k_d': 200.0, 'k_a': 6000.0})
