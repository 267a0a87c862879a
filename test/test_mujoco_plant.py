"""
The MuJoCo plant (``physics:=mujoco``) offline: fidelity, contact, sensor, friction, the engine.

* MuJoCo's mass matrix and bias forces match pinocchio's on the same URDF at random states,
  for the paper's arm (point masses) and the Panda (fingers welded);
* a static press at 2, 5 and 20 N gives the stiffness parameter (N/m) within 2 %;
* the wrist sensor reads the tool's weight out of contact, and in contact the true contact
  force plus the weight, in the end-effector frame;
* the true contact force (the table top's ``cfrc_ext``) is MuJoCo's contact force, friction
  included;
* with friction mu the tool sticks under a side push below mu f_n and slides above it;
* a disc tool (``tool_shape``) flat on the surface reads no moment at the wrist; tilted, it
  touches on its rim and the wrist reads the moment, the force times the rim's lever; a
  sphere's contact force passes through its centre (no moment);
* the offline engine runs the controller against it (the plant interface of ArmSimulator);
* bad MuJoCo settings are refused with a typed error.
"""
from __future__ import annotations

from helpers.offline import mujoco_arm, mujoco_press, R_TOOL
from hybrid_force_controller.core.config.params import build_params, ParameterValidationError
from hybrid_force_controller.core.model.robot_model import default_urdf_path, RobotModel
from hybrid_force_controller.core.offline.engine import run_loop
from hybrid_force_controller.core.offline.environment import (ElasticSurface,
                                                              sensor_wrench_from_f_W, SurfaceError)
from hybrid_force_controller.core.offline.timing import TimingModel
from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime
import mujoco
import numpy as np
import pinocchio as pin
import pytest
from sim_node.mujoco_params import check_physics, mujoco_options, MujocoOptions
from sim_node.mujoco_plant import MujocoPlant
from sim_node.plants import touch_offset


def _plant(name, k=1700.0, **opts):
    model, urdf, q0, n_W = mujoco_arm(name)
    p0 = model.kinematics(q0, np.zeros(model.n)).p_W
    surface = ElasticSurface.create(k, p0 + R_TOOL * n_W, n_W)  # touching the sphere
    plant = MujocoPlant(model, urdf, MujocoOptions(tool_radius=R_TOOL, **opts), surface, q0)
    return model, plant, n_W


@pytest.mark.parametrize('name', ['paper', 'panda'])
def test_mass_matrix_and_bias_forces_match_pinocchio(name):
    model, plant, _ = _plant(name)
    m, d, sc = plant.m, plant.d, plant.scene
    rng = np.random.default_rng(7)
    worst_M = worst_b = 0.0
    for _ in range(20):
        q, v = rng.uniform(-2.0, 2.0, model.n), rng.normal(0.0, 1.0, model.n)
        d.qpos[sc.qpos], d.qvel[sc.dof] = q, v
        mujoco.mj_forward(m, d)
        M = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        M_pin = pin.crba(model.model, model.data, q)
        M_pin = np.triu(M_pin) + np.triu(M_pin, 1).T
        b_pin = pin.rnea(model.model, model.data, q, v, np.zeros(model.n))
        worst_M = max(worst_M, np.abs(M[np.ix_(sc.dof, sc.dof)] - M_pin).max())
        worst_b = max(worst_b, np.abs(d.qfrc_bias[sc.dof] - b_pin).max())
    print(f'{name}: max |M - M_pin| = {worst_M:.2e}, max |b - b_pin| = {worst_b:.2e}')
    assert worst_M <= 1e-9 and worst_b <= 1e-9, (worst_M, worst_b)


@pytest.mark.parametrize('name, k', [('paper', 1700.0), ('panda', 3000.0)])
def test_static_press_gives_the_stiffness_parameter(name, k):
    model, plant, n_W = _plant(name, k, surface_damping=20.0)
    for f_n in (2.0, 5.0, 20.0):
        meas = mujoco_press(model, plant, f_n * n_W)
        depth = float(n_W @ (meas.p_W - plant.surface.x0_W)) + R_TOOL
        f_true_n = float(n_W @ meas.f_true_W)
        print(f'{name}: {f_n:g} N: k = {f_true_n / depth:.2f} N/m (parameter {k:g})')
        assert f_true_n == pytest.approx(f_n, rel=1e-3)
        assert f_true_n / depth == pytest.approx(k, rel=0.02)


def test_sensor_reads_the_tool_weight_and_the_contact_force():
    model, plant, n_W = _plant('panda', 3000.0, tool_mass=0.25)
    g_W = model.model.gravity.linear
    surface = plant.surface
    plant.surface = None  # out of contact, brakes on: the sensor feels the weight only
    meas = plant.hold(1e-3)
    F_S = sensor_wrench_from_f_W(meas.R_W_ee, meas.f_W)
    np.testing.assert_allclose(F_S, 0.25 * meas.R_W_ee.T @ g_W, atol=1e-9)
    assert np.all(meas.f_true_W == 0.0)
    plant.surface = surface
    meas = mujoco_press(model, plant, 5.0 * n_W)  # at rest, pressing 5 N (the weight included)
    F_S = sensor_wrench_from_f_W(meas.R_W_ee, meas.f_W)
    # the reading is the environment's force on the tool plus the weight, tool frame
    np.testing.assert_allclose(F_S, meas.R_W_ee.T @ (-meas.f_true_W + 0.25 * g_W), atol=1e-6)
    assert float(n_W @ meas.f_true_W) == pytest.approx(5.0 + 0.25 * 9.81, rel=1e-3)


def test_friction_holds_below_mu_fn_and_slides_at_it():
    # the planar arm: its tool cannot roll (a 7-DOF arm with a free orientation can)
    model, plant, n_W = _plant('paper', 1700.0, surface_friction=0.3)
    t_W = np.array([1.0, 0.0, 0.0])
    mujoco_press(model, plant, 5.0 * n_W)  # mu f_n = 1.5 N

    def push(f_t):
        mujoco_press(model, plant, 5.0 * n_W + f_t * t_W, steps=500)
        x0 = plant.measure().p_W
        meas = mujoco_press(model, plant, 5.0 * n_W + f_t * t_W, steps=500)
        return float(t_W @ (meas.p_W - x0)) / 0.5, meas  # m/s over the last 0.5 s
    v_held, _ = push(1.0)
    v_slid, meas = push(2.0)
    f_n = float(n_W @ meas.f_true_W)
    print('held', v_held, 'slid', v_slid)
    assert abs(v_held) <= 2e-3, v_held  # at most a slow creep (MuJoCo's friction is soft)
    assert v_slid > 10e-3, v_slid
    assert abs(t_W @ meas.f_true_W) == pytest.approx(0.3 * f_n, rel=0.03)


def test_the_engine_runs_the_controller_against_mujoco_offline():
    model, plant, n_W = _plant('paper')
    runtime = ControllerRuntime(model, build_params(model))
    log = run_loop(runtime, plant, 8.0, TimingModel.lockstep(1))
    after = log.t >= 5.0
    P_t = np.eye(3) - np.outer(n_W, n_W)
    e_x = np.sqrt(np.mean(np.sum(((log.x_W - log.x_d_W)[after] @ P_t) ** 2, axis=1)))
    e_f = np.sqrt(np.mean((log.f_true_W[after] @ n_W - 1.0) ** 2))
    assert e_x <= 0.5e-3 and e_f <= 0.05, (e_x, e_f)
    assert np.all(np.isfinite(log.tau))
    assert np.all(log.f_true_W[log.t >= 1.0] @ n_W > 0.5)  # contact kept after the touch


@pytest.mark.parametrize('values, words', [
    ({'tool_radius': 0.0}, 'tool_radius must be > 0'),
    ({'surface_friction': -0.1}, 'surface_friction'),
    ({'tool_mass': float('nan')}, 'tool_mass must be a finite number'),
    ({'joint_limits': 'yes'}, 'joint_limits must be true or false'),
    ({'tool_shape': 'cube'}, "tool_shape must be one of \\['sphere', 'disc'\\]"),
])
def test_bad_mujoco_options_are_refused(values, words):
    with pytest.raises(ParameterValidationError, match=words):
        mujoco_options(values)


def test_unknown_physics_and_unknown_tool_link_are_refused():
    with pytest.raises(ParameterValidationError, match='physics must be one of'):
        check_physics('bullet')
    model = RobotModel.from_urdf(end_effector_link='link2')
    model.end_effector_link = 'no_such_link'
    with pytest.raises(ParameterValidationError, match='no_such_link'):
        MujocoPlant(model, default_urdf_path(), MujocoOptions(), None, np.zeros(2))


def test_run_time_surface_changes_move_the_table_and_bound_its_stiffness():
    model, plant, n_W = _plant('paper', 1700.0)
    surface = plant.surface
    plant.surface = ElasticSurface.create(4.0 * 1700.0, surface.x0_W + 0.01 * n_W, n_W)
    meas = mujoco_press(model, plant, 5.0 * n_W)  # 1 cm further: 1 cm more to travel
    depth = float(n_W @ (meas.p_W - plant.surface.x0_W)) + R_TOOL
    assert float(n_W @ meas.f_true_W) / depth == pytest.approx(4.0 * 1700.0, rel=0.02)
    with pytest.raises(SurfaceError, match='too high for the plate'):
        plant.surface = ElasticSurface.create(5.0 * 1700.0, surface.x0_W, n_W)


@pytest.mark.parametrize('name', ['paper', 'panda'])
def test_a_step_that_reuses_measures_forward_pass_is_bitwise_the_full_mj_step(name):
    """step() runs only the acceleration stage after measure() (mujoco_plant.py): same numbers."""
    runs = []
    for reuse in (False, True):
        model, plant, n_W = _plant(name)
        plant.reuse_forward = reuse
        # in contact: the constraint solver
        meas = mujoco_press(model, plant, 5.0 * n_W, steps=300)
        runs.append((meas.q, meas.qdot, meas.f_W, meas.f_true_W))
    for full, reused in zip(*runs):
        np.testing.assert_array_equal(full, reused)
    assert np.linalg.norm(runs[0][3]) > 1.0  # pressing, so the contact path was exercised


def _contact_forces_on_surface_W(plant):
    """Sum mj_contactForce over the contacts: the force the tool exerts on the surface, base."""
    d, f_root, f6 = plant.d, np.zeros(3), np.zeros(6)
    for i in range(d.ncon):
        mujoco.mj_contactForce(plant.m, d, i, f6)
        contact = d.contact[i]
        on_2 = contact.frame.reshape(3, 3).T @ f6[:3]  # geom1 on geom2, contact frame -> world
        f_root += on_2 if contact.geom1 == plant.scene.tool_geom else -on_2
    return plant.scene.R_W_root @ f_root


@pytest.mark.parametrize('name', ['paper', 'panda'])
def test_true_force_is_the_sum_of_mujocos_contact_forces(name):
    """f_true_W, read from the table top's cfrc_ext, is the contact force, friction included."""
    model, plant, n_W = _plant(name, 3000.0, surface_friction=0.3, tool_mass=0.25)
    t_W = np.cross(n_W, [0.0, 0.0, 1.0] if abs(n_W[2]) < 0.9 else [1.0, 0.0, 0.0])
    meas = mujoco_press(model, plant, 5.0 * n_W + 3.0 * t_W, steps=300)  # sliding: friction rows
    np.testing.assert_allclose(meas.f_true_W, _contact_forces_on_surface_W(plant), atol=1e-12)
    assert abs(t_W @ meas.f_true_W) > 0.5 and n_W @ meas.f_true_W > 2.0, meas.f_true_W
    meas = plant.hold(1e-3)  # the brakes: inverse dynamics, the same contact read
    np.testing.assert_allclose(meas.f_true_W, _contact_forces_on_surface_W(plant), atol=1e-12)
    plant.surface = None
    assert np.all(plant.step(np.zeros(model.n), 1e-3).f_true_W == 0.0)


def _rot_y(v, angle):
    c, s = np.cos(angle), np.sin(angle)
    return np.array([c * v[0] + s * v[2], v[1], -s * v[0] + c * v[2]])


@pytest.mark.parametrize('shape, tilt', [('disc', 0.0), ('disc', 0.3), ('sphere', 0.3)])
def test_a_disc_reads_the_moment_of_its_rim_a_sphere_none(shape, tilt):
    """The arm braked at q0, the surface 1 mm into the tool (its normal tilt rad off the axis)."""
    model, urdf, q0, _ = mujoco_arm('panda')
    kin = model.kinematics(q0, np.zeros(model.n))
    axis_W, r = kin.R_W_ee[:, 2], 0.03
    n_W = _rot_y(axis_W, tilt)
    reach = touch_offset({'physics': 'mujoco', 'tool_radius': r, 'tool_shape': shape},
                         axis_W)(n_W)
    surface = ElasticSurface.create(3000.0, kin.p_W + (reach - 0.001) * n_W, n_W)
    plant = MujocoPlant(model, urdf, MujocoOptions(tool_radius=r, tool_shape=shape), surface,
                        q0)
    f = np.linalg.norm(plant.hold(1e-3).f_true_W)
    tau = np.linalg.norm(plant.torque_S)
    print(f'{shape} tilted {tilt} rad: |f| {f:.3g} N, |tau| {tau:.3g} N m, tau / (r f) '
          f'{tau / (r * f):.3f}, contacts {plant.d.ncon}')
    assert f > 1.0
    if shape == 'disc' and tilt > 0.0:  # on its rim: the lever is about r (0.94 r measured)
        assert tau > 0.8 * r * f and plant.d.ncon == 1
    else:  # flat (four contacts, symmetric), or a sphere's force through its centre
        assert tau < 1e-3 * r * f


def test_a_disc_on_the_papers_physics_is_refused_with_the_reason():
    from sim_node.plants import make_plant
    model, urdf, q0, _ = mujoco_arm('paper')
    v = {'physics': 'paper', 'tool_shape': 'disc', 'masses': [], 'substeps': 1,
         'noise_sigma': 0.0, 'seed': 0}
    with pytest.raises(ParameterValidationError, match='needs physics:=mujoco'):
        make_plant(v, model, str(urdf), None, q0)


def test_the_disc_reaches_a_surface_by_its_rim_and_its_face():
    v = {'physics': 'mujoco', 'tool_radius': 0.03, 'tool_shape': 'disc'}
    axis_W = np.array([0.0, 0.0, -1.0])
    reach = touch_offset(v, axis_W)
    assert reach(axis_W) == pytest.approx(0.002)  # its face: half the 4 mm
    assert reach(np.array([1.0, 0.0, 0.0])) == pytest.approx(0.03)  # edge on: its rim
    n = _rot_y(axis_W, 0.3)
    assert reach(n) == pytest.approx(0.03 * np.sin(0.3) + 0.002 * np.cos(0.3))
    assert touch_offset(dict(v, tool_shape='sphere'), axis_W)(n) == 0.03
    assert touch_offset(dict(v, physics='paper'), axis_W)(n) == 0.0
