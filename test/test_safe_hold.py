"""
SafeHold (core/runtime/effort.py) after a stall: a hold begun on a stale state holds no old pose.

After a 300 ms freeze of the controller, its first tick sees the joint state from before the
freeze (the arm meanwhile fell 4.5 cm onto the surface, real time) and enters safe mode on
it. Held to that stale position once the fresh states came, the impedance pulled the arm
back at the effort limits: the paper's arm flung off the surface or pressed into it at
426-512 N (docs/results.md, section 16).
"""
from __future__ import annotations

from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.scenario import PAPER_Q0
from hybrid_force_controller.core.runtime.effort import SafeHold
import numpy as np
import pytest

K_D, LAMBDA1, K_NULL = 6000.0, 40.0, 0.0  # config/params.yaml's law
THETA = np.array([0.65, 1.35])
F_W = np.array([0.0, -1.0, 0.0])


@pytest.fixture(scope='module')
def arm():
    model = RobotModel.from_urdf()
    q_before = np.array(PAPER_Q0)
    q_now = q_before + np.array([0.02, -0.03])  # where the arm fell during the stall
    return model, q_before, q_now


def _effort(model, q_latch, fresh_latch, q_now, qdot_now):
    hold = SafeHold(model)
    hold.latch(1.0, F_W, q_latch, np.zeros(2), THETA, None, fresh_latch)
    tau, _ = hold.effort(1.001, q_now, qdot_now, THETA, K_D, LAMBDA1, K_NULL, True)
    return tau


def test_a_hold_begun_on_a_stale_state_starts_from_the_first_fresh_one(arm):
    model, q_before, q_now = arm
    qdot = np.array([0.3, -0.2])
    stale = _effort(model, q_before, False, q_now, qdot)
    # the effort of a hold begun at that fresh state, at that tick: no pull toward q_before
    hold = SafeHold(model)
    hold.latch(1.001, F_W, q_now, qdot, THETA, None, True)
    expected, _ = hold.effort(1.001, q_now, qdot, THETA, K_D, LAMBDA1, K_NULL, True)
    np.testing.assert_allclose(stale, expected, rtol=1e-9, atol=1e-9)
    assert np.abs(_effort(model, q_before, True, q_now, qdot) - stale).max() > 100.0


def test_a_hold_begun_on_a_fresh_state_still_holds_its_position(arm):
    """The negative control: latched fresh, the hold pulls back toward its own position."""
    model, q_before, q_now = arm
    pulled = _effort(model, q_before, True, q_now, np.zeros(2))
    here = _effort(model, q_now, True, q_now, np.zeros(2))
    assert np.abs(pulled - here).max() > 100.0  # a 3 cm error at K_D lambda1 = 240 kN/m
