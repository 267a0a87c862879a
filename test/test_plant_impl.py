"""
The compiled plant against its Python reference (issue 33, item 4; plant_kernels.py).

``ArmSimulator(impl='compiled')`` steps the arm in one numba call (kinematics, the surface's
spring, ABA); ``impl='python'`` is the reference (pinocchio's ABA). Both are driven with the
same efforts and must agree to a relative 1e-12 at every step: the paper's arm and the Panda
on each surface shape with joint friction, an arm with an unaligned revolute axis, a prismatic
joint and a rotated base frame, a surface moved mid-run, the brakes and a NaN effort.
"""
from __future__ import annotations

from hybrid_force_controller.core.model.linalg import all_finite
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.arm7 import panda_model, PANDA_Q0
from hybrid_force_controller.core.offline.environment import make_surface, SURFACE_SHAPES
from hybrid_force_controller.core.offline.plant_compiled import (compiled_plant,
                                                                 plant_kernels_cached)
from hybrid_force_controller.core.offline.scenario import PAPER_Q0, run_scenario, ScenarioConfig
from hybrid_force_controller.core.offline.simulator import ArmSimulator, SimulatorError
import numpy as np
import pytest

REL = 1e-12  # measured: 2e-13 over 500 steps
ODD_URDF = """<?xml version="1.0"?>
<robot name="odd">
  <link name="world"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base"/>
    <origin xyz="0.1 -0.2 0.3" rpy="0.3 -0.2 0.5"/></joint>
  <link name="base"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.2" rpy="0.1 0 0"/><axis xyz="0 0.6 0.8"/>
    <limit lower="-3" upper="3" effort="50" velocity="5"/></joint>
  <link name="l1"><inertial><origin xyz="0.1 0 0.05" rpy="0 0.2 0"/><mass value="1.1"/>
    <inertia ixx="0.02" ixy="0.001" ixz="0" iyy="0.03" iyz="0.002" izz="0.01"/></inertial></link>
  <joint name="j2" type="prismatic"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.3 0 0" rpy="0 0 0.4"/><axis xyz="1 0 0"/>
    <limit lower="-0.5" upper="0.5" effort="50" velocity="1"/></joint>
  <link name="l2"><inertial><origin xyz="0.05 0.02 0" rpy="0 0 0"/><mass value="0.7"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.02"/></inertial></link>
  <joint name="j3" type="revolute"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.2 0 0.1" rpy="0 0.5 0"/><axis xyz="0 0 1"/>
    <limit lower="-3" upper="3" effort="50" velocity="5"/></joint>
  <link name="l3"><inertial><origin xyz="0.1 0 0" rpy="0 0 0"/><mass value="0.5"/>
    <inertia ixx="0.004" ixy="0" ixz="0" iyy="0.005" iyz="0" izz="0.006"/></inertial></link>
  <joint name="tool" type="fixed"><parent link="l3"/><child link="tool0"/>
    <origin xyz="0.15 0.02 0" rpy="0.2 0 0.3"/></joint>
  <link name="tool0"/>
</robot>
"""


def _arms() -> dict[str, tuple[RobotModel, np.ndarray, np.ndarray]]:
    """Each arm, its start and the surface's normal there."""
    odd = RobotModel.from_urdf(ODD_URDF, base_link='base', gravity_root=(0.0, 0.0, -9.81))
    return {'paper': (RobotModel.from_urdf(), np.array(PAPER_Q0), np.array([0.0, -1.0, 0.0])),
            'panda': (panda_model(), np.array(PANDA_Q0), np.array([0.0, 0.0, -1.0])),
            'odd': (odd, np.array([0.3, 0.1, -0.4]), np.array([0.0, 0.6, -0.8]))}


ARMS = _arms()


def _pair(name: str, shape: str, **kwargs) -> list[ArmSimulator]:
    model, q0, n_W = ARMS[name]
    p0 = model.kinematics(q0, np.zeros(model.n)).p_W
    surface = make_surface(shape, 3000.0, p0 - 0.002 * n_W, n_W, 0.3)
    sims = [ArmSimulator(model.with_theta(1.2 * model.theta_nominal), surface, q0, substeps=3,
                         impl=impl, **kwargs) for impl in ('compiled', 'python')]
    assert [s.impl for s in sims] == ['compiled', 'python'], sims[0].impl_note
    return sims


def _assert_same(a, b) -> None:
    """Every field of two measurements equal to REL of its size."""
    assert a.in_contact == b.in_contact
    for name, x, y in zip(a._fields[:-1], a, b):
        scale = 1.0 + np.max(np.abs(y))
        assert np.max(np.abs(np.asarray(x) - y)) <= REL * scale, (name, x, y)


def _drive(sims: list[ArmSimulator], steps: int, seed: int = 4) -> list:
    """Step both with the same random efforts; return the compiled one's contacts."""
    rng, contacts = np.random.default_rng(seed), []
    for _ in range(steps):
        tau = rng.normal(0.0, 3.0, sims[0].model.n)
        a, b = (s.step(tau, 1e-3) for s in sims)
        _assert_same(a, b)
        contacts.append(a.in_contact)
    return contacts


@pytest.mark.parametrize('shape', SURFACE_SHAPES)
@pytest.mark.parametrize('arm', sorted(ARMS))
def test_the_compiled_step_is_the_reference(arm, shape):
    sims = _pair(arm, shape, friction_viscous=0.2, friction_coulomb=0.1)
    _assert_same(*(s.measure() for s in sims))
    contacts = _drive(sims, 400)
    assert any(contacts), 'the surface was never touched: the spring went untested'


def test_a_surface_moved_between_steps_is_the_one_stepped():
    sims = _pair('panda', 'plane')
    _drive(sims, 50)
    moved = make_surface('sphere', 5000.0, sims[1].measure().p_W, [0.0, 0.0, -1.0], 0.1)
    for s in sims:
        s.surface = moved
    _assert_same(*(s.measure() for s in sims))
    assert any(_drive(sims, 100, seed=5))
    for s in sims:
        s.surface = None
    assert not any(_drive(sims, 50, seed=6))


def test_the_brakes_and_a_bad_effort():
    sims = _pair('paper', 'plane')
    _drive(sims, 30)
    _assert_same(*(s.hold(0.01) for s in sims))
    for s in sims:
        with pytest.raises(SimulatorError, match='finite'):
            s.step(np.array([np.nan, 0.0]), 1e-3)
    _assert_same(*(s.measure() for s in sims))  # the refused effort changed nothing
    with pytest.raises(SimulatorError, match='plant_impl'):
        ArmSimulator(ARMS['paper'][0], None, np.zeros(2), impl='fast')


@pytest.mark.parametrize('x, finite', [
    ([1.0, -2.0], True), ([1e308, 1e308], True),  # their sum overflows: still finite
    ([np.nan, 0.0], False), ([np.inf, 0.0], False), ([-np.inf, np.inf], False)])
def test_all_finite_accepts_every_finite_effort_and_no_other(x, finite):
    assert all_finite(np.array(x)) is finite
    if not finite:  # the plant refuses it, whichever runs
        for impl in ('compiled', 'python'):
            with pytest.raises(SimulatorError, match='finite'):
                ArmSimulator(ARMS['paper'][0], None, np.zeros(2), impl=impl).step(
                    np.array(x), 1e-3)


def test_the_compiled_plant_loads_its_kernels_and_says_so():
    plant, note = compiled_plant(ARMS['panda'][0])
    assert plant is not None and note.startswith('plant_impl compiled: numba kernels ')
    assert plant_kernels_cached()  # what the sim reads to say it compiles on a first start


def test_the_paper_scenario_is_the_same_with_either_plant():
    runs = [run_scenario(ScenarioConfig(duration=2.0, theta_hat0_scale=0.5, plant_impl=impl))
            for impl in ('compiled', 'python')]
    for name in ('tau', 'x_W', 'f_true_W', 'theta_hat'):
        x, y = (np.asarray(getattr(r.log, name)) for r in runs)
        assert np.max(np.abs(x - y)) <= REL * np.max(np.abs(y)), name
