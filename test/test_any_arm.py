"""
Any arm from a URDF: redundant, spatial and 7-DOF arms, parameter sets, bad chains.

Closed loops run on the offline simulator (pure numpy + pinocchio, fixed seeds) beside the other
offline modules; the last test starts the controller node for the Panda as a subprocess in its
own ROS domain (``dds``: it alone runs in the serial group, conftest.py).
"""
from pathlib import Path

from helpers.pins import check_pinned, numbers
from helpers.ros import CONTROLLER_MODULE, domain_id, NodeProcess, Spun, wait_for, wait_future
from hybrid_force_controller.core.model.parameter_sets import project_physical
from hybrid_force_controller.core.model.robot_model import (default_urdf_path, ModelError,
                                                            RobotModel)
from hybrid_force_controller.core.offline import scenario as scenario_module
from hybrid_force_controller.core.offline.arm7 import (PANDA_JOINTS, panda_model, PANDA_Q0,
                                                       panda_scenario, panda_urdf_path)
from hybrid_force_controller.core.offline.scenario import PAPER_Q0, run_scenario, ScenarioConfig
from hybrid_force_controller.core.offline.simulator import ArmSimulator
from hybrid_force_controller.tools.analysis import compute_metrics, RunLog
import numpy as np
import pinocchio as pin
import pytest


PLANAR3 = Path(__file__).resolve().parent / 'three_link_planar.urdf'
SPATIAL3 = Path(__file__).resolve().parent / 'three_link_spatial.urdf'
DOMAIN_ID = domain_id('any_arm')
Z_UP = (0.0, 0.0, -9.81)


# --------------------------------------------------------------------------- helpers
class _RecordingSimulator(ArmSimulator):
    """The scenario's plant, also recording (t, q, qdot) after every control period."""

    records: list = []

    def step(self, tau, dt):
        meas = super().step(tau, dt)
        type(self).records.append((meas.t, meas.q.copy(), meas.qdot.copy()))
        return meas


def _run_recorded(monkeypatch, cfg, model):
    """run_scenario with the plant's joint trajectory recorded: (result, t, q, qdot)."""
    _RecordingSimulator.records = []
    monkeypatch.setattr(scenario_module, 'ArmSimulator', _RecordingSimulator)
    result = run_scenario(cfg, model)
    rec = _RecordingSimulator.records
    assert len(rec) == len(result.t)
    return (result, np.array([r[0] for r in rec]), np.array([r[1] for r in rec]),
            np.array([r[2] for r in rec]))


def _tool_start(model, q0):
    return model.kinematics(np.array(q0, dtype=float), np.zeros(model.n)).p_W


def _null_space_speed(model, q, qdot):
    """|N qdot| with N = I - Jbar J, Jbar the dynamically consistent inverse."""
    kin = model.kinematics(q, qdot)
    J = kin.J_ee
    JM = J @ model.inertia_inverse(q)
    J_bar = JM.T @ np.linalg.inv(JM @ J.T)
    return float(np.linalg.norm((np.eye(model.n) - J_bar @ J) @ qdot))


# --------------------------------------------------------------------------- 1. 3-link arms
PLANAR3_Q0 = (0.3, 0.9, 0.8)  # elbows bent; singular values of J 2.25 and 0.70


def test_planar_redundant_arm_closed_loop(monkeypatch):
    model = RobotModel.from_urdf(PLANAR3, end_effector_link='tool0')
    assert model.n == 3 and model.task_axes == (0, 1) and model.redundant
    assert np.linalg.svd(model.kinematics(np.array(PLANAR3_Q0), np.zeros(3)).J_ee)[1].min() > 0.5
    p0 = _tool_start(model, PLANAR3_Q0)
    cfg = ScenarioConfig(q0=PLANAR3_Q0, k=1700.0, duration=20.0, theta_hat0_scale=0.7,
                         overrides={'ref_center': p0.tolist(), 'ref_amplitude': [0.1, 0.0, 0.0],
                                    'n': [0.0, -1.0, 0.0]})
    result, t, q, qdot = _run_recorded(monkeypatch, cfg, model)
    met = compute_metrics(RunLog.from_result(result), t_start=5.0)
    assert met['rms_position_error_m'] <= 1e-3, met
    assert met['rms_force_error_n'] <= 0.05, met
    assert met['contact_lost_s'] == 0.0 and result.in_contact[result.t >= 0.1].all(), met
    # joint speeds stay bounded; the tool moves at <= 0.1 m/s, so ~0.1 rad/s is task motion
    assert np.all(np.isfinite(qdot))
    assert np.abs(qdot).max() <= 0.5
    last = t >= t[-1] - 5.0
    assert np.abs(qdot[last]).max() <= 0.15
    # null-space motion is damped out: no self-motion at the end ...
    assert max(_null_space_speed(model, qi, qdi)
               for qi, qdi in zip(q[last][::50], qdot[last][::50])) <= 1e-3
    # ... and the posture is periodic with the reference (no drift along the self-motion)
    i1, i2 = (int(np.argmin(np.abs(t - c))) for c in (4.0 * np.pi, 6.0 * np.pi))
    assert np.abs(q[i2] - q[i1]).max() <= 1e-3, q[i2] - q[i1]


def test_spatial_square_arm_closed_loop():
    model = RobotModel.from_urdf(SPATIAL3, end_effector_link='tool0', gravity_root=Z_UP)
    assert model.n == 3 and model.task_axes == (0, 1, 2) and not model.redundant
    q0 = (0.2, 0.3, 1.0)  # singular values of J 1.26 / 0.83 / 0.28
    p0 = _tool_start(model, q0)
    cfg = ScenarioConfig(q0=q0, k=1700.0, duration=15.0, theta_hat0_scale=0.7,
                         overrides={'ref_center': p0.tolist(), 'ref_amplitude': [0.1, 0.0, 0.0],
                                    'n': [0.0, 0.0, -1.0]})
    result = run_scenario(cfg, model)
    met = compute_metrics(RunLog.from_result(result), t_start=5.0)
    assert met['rms_position_error_m'] <= 1e-3, met
    assert met['rms_force_error_n'] <= 0.05, met
    assert met['contact_lost_s'] == 0.0 and result.in_contact[result.t >= 0.1].all(), met
    # the force acts along -z (n) and the tool really moves along x
    assert np.allclose(result.f_W[-1] / np.linalg.norm(result.f_W[-1]), [0.0, 0.0, -1.0],
                       atol=1e-3)
    assert np.ptp(result.x_W[:, 0]) >= 0.15


# --------------------------------------------------------------------------- 2. Panda
@pytest.fixture(scope='module')
def panda():
    return panda_model()


def test_panda_model_is_7dof_redundant(panda):
    assert panda.n == 7 and panda.joint_names == PANDA_JOINTS  # fingers locked
    assert panda.task_axes == (0, 1, 2) and panda.redundant
    assert len(panda.theta_nominal) == 7 and np.all(panda.theta_nominal > 0)


def test_panda_closed_loop_with_mass_errors(panda):
    cfg = panda_scenario(panda, 20.0)
    scale = np.asarray(cfg.theta_hat0_scale, dtype=float)
    assert scale.shape == (7,) and np.allclose(np.abs(scale - 1.0), 0.3)
    result = run_scenario(cfg, panda)
    met = compute_metrics(RunLog.from_result(result), t_start=5.0)
    assert met['rms_position_error_m'] <= 1e-3, met
    assert met['rms_force_error_n'] <= 0.05, met
    assert met['contact_lost_s'] == 0.0, met
    assert np.ptp(result.x_W[:, 0]) >= 0.08  # it really traced the 10 cm line
    check_pinned('panda', numbers(met))  # test_pinned_figures.py's docstring


# --------------------------------------------------------------------------- 3. parameter sets
def _payload_theta():
    """Return a 1.5 kg near-point load 5 cm off the end body's joint origin, small inertia."""
    return pin.Inertia(1.5, np.array([0.05, 0.0, 0.02]),
                       np.diag([2e-3, 3e-3, 4e-3])).toDynamicParameters()


def _full_theta(model):
    """Return the nominal pi with each body's mass and rotational inertia rescaled (consistent)."""
    rng = np.random.default_rng(7)
    out = []
    for j in range(1, model.model.njoints):
        inertia = model.model.inertias[j]
        a, b = rng.uniform(0.6, 1.5, 2)
        out.append(pin.Inertia(a * inertia.mass, inertia.lever.copy(),
                               b * inertia.inertia).toDynamicParameters())
    return np.concatenate(out)


def _two_link(parameter_set):
    return RobotModel.from_urdf(parameter_set=parameter_set)


def _panda(parameter_set):
    return panda_model(parameter_set)


@pytest.mark.parametrize('make', [_two_link, _panda], ids=['2link', 'panda'])
@pytest.mark.parametrize('parameter_set', ['payload', 'full'])
def test_regressor_matches_rnea_of_with_theta(make, parameter_set):
    model = make(parameter_set)
    theta = _payload_theta() if parameter_set == 'payload' else _full_theta(model)
    assert theta.shape == model.theta_nominal.shape
    plant = model.with_theta(theta)
    rng = np.random.default_rng(3)
    for _ in range(3):
        q = rng.uniform(-1.0, 1.0, model.n)
        v, a = rng.normal(size=model.n), rng.normal(size=model.n)
        Y, tau_0 = model.regressor_affine(q, v, v, a)
        tau = Y @ theta + (0.0 if tau_0 is None else tau_0)
        expected = pin.rnea(plant.model, plant.model.createData(), q, v, a)
        assert np.allclose(tau, expected, rtol=1e-9, atol=1e-9), (tau, expected)
        # and theta really changed the dynamics (the comparison is not vacuous)
        nominal = pin.rnea(model.model, model.model.createData(), q, v, a)
        assert np.abs(expected - nominal).max() > 1e-3


def _assert_consistent(pi10):
    inertia = pin.Inertia.FromDynamicParameters(np.asarray(pi10))
    assert inertia.mass > 0.0
    lam = np.linalg.eigvalsh(inertia.inertia)  # about the centre of mass, ascending
    assert lam.min() >= -1e-12, lam
    assert lam[2] <= lam[0] + lam[1] + 1e-12, lam  # triangle inequalities


def test_project_physical_repairs_inconsistent_bodies():
    good = pin.Inertia(2.0, np.array([0.1, -0.05, 0.2]),
                       np.array([[0.05, 0.01, 0.0], [0.01, 0.04, 0.005],
                                 [0.0, 0.005, 0.03]])).toDynamicParameters()
    negative_mass = good.copy()
    negative_mass[0] = -0.5
    non_psd = good.copy()
    non_psd[4:] = [-0.2, 0.3, 0.01, 0.0, 0.0, -0.4]  # indefinite inertia about the origin
    thin = pin.Inertia(1.0, np.zeros(3), np.diag([0.01, 0.01, 0.5])).toDynamicParameters()
    assert thin[9] > thin[4] + thin[6]  # violates the triangle inequality
    theta = np.concatenate([negative_mass, non_psd, thin])
    projected = project_physical(theta)
    assert projected.shape == theta.shape and np.all(np.isfinite(projected))
    for b in range(0, projected.size, 10):
        _assert_consistent(projected[b:b + 10])
    # a consistent vector is a fixed point
    consistent = np.concatenate([good, _full_theta(panda_model('full'))])
    assert np.allclose(project_physical(consistent), consistent, rtol=0.0, atol=1e-9)


def test_paper_scenario_with_payload_set():
    model = RobotModel.from_urdf(parameter_set='payload')
    assert model.parameter_set.name == 'payload' and len(model.theta_nominal) == 10
    assert not np.any(model.theta_nominal)  # theta_hat(0) = 0, the true payload is 0
    # the plant is the plain URDF: pi_0 holds exactly its inertias
    plain = RobotModel.from_urdf()
    for j in range(1, plain.model.njoints):
        assert np.allclose(model.model.inertias[j].toDynamicParameters(),
                           plain.model.inertias[j].toDynamicParameters())
    result = run_scenario(ScenarioConfig(duration=20.0), model)
    met = compute_metrics(RunLog.from_result(result), t_start=5.0)
    assert met['rms_position_error_m'] <= 2e-4, met
    assert met['rms_force_error_n'] <= 0.02, met
    assert met['contact_lost_s'] == 0.0, met
    assert abs(result.theta_hat[-1][0]) <= 0.1  # no phantom payload mass


# --------------------------------------------------------------------------- 4. bad chains
@pytest.mark.parametrize('build, words', [
    (lambda: RobotModel.from_urdf(joints=['joint1']), ['fewer joints than the task needs']),
    (lambda: RobotModel.from_urdf(joints=['joint1', 'elbow']), ['not in the URDF', 'elbow']),
    (lambda: RobotModel.from_urdf(end_effector_link='flange'), ['end-effector', 'flange']),
    (lambda: RobotModel.from_urdf(base_link='link1'), ['link1', 'joint1', 'fixed']),
    (lambda: RobotModel.from_urdf(base_link='nowhere'), ['base link', 'nowhere']),
    (lambda: RobotModel.from_urdf(parameter_set='everything'),
     ['unknown parameter set', 'everything']),
    (lambda: RobotModel.from_parameters({'gravity': [0, 1]}), ['gravity', '3']),
], ids=['too_few_joints', 'unknown_joint', 'unknown_ee', 'moving_base', 'unknown_base',
        'unknown_set', 'bad_gravity'])
def test_unusable_chain_is_rejected(build, words):
    with pytest.raises(ModelError) as info:
        build()
    for word in words:
        assert word in str(info.value), str(info.value)


# --------------------------------------------------------------------------- 5. base_link
BASE_XYZ, BASE_RPY = np.array([0.3, -0.2, 0.5]), (0.2, -0.4, 0.7)
R_root_W = pin.rpy.rpyToMatrix(*BASE_RPY)


def _two_link_on_a_stand():
    """Return the bundled 2-link URDF below a new root ``world``, base_link placed rotated."""
    text = default_urdf_path().read_text()
    anchor = '<link name="base_link"/>'
    assert text.count(anchor) == 1
    extra = ('<link name="world"/>\n<joint name="world_to_base" type="fixed">'
             '<parent link="world"/><child link="base_link"/>'
             f'<origin xyz="{" ".join(map(str, BASE_XYZ))}" rpy="{" ".join(map(str, BASE_RPY))}"/>'
             '</joint>\n')
    return text.replace(anchor, extra + anchor)


def test_task_space_is_expressed_in_base_link():
    urdf = _two_link_on_a_stand()
    gravity_root = R_root_W @ np.array([0.0, -9.81, 0.0])  # the paper's gravity, in the new root
    model = RobotModel.from_urdf(urdf, base_link='base_link', gravity_root=gravity_root)
    plain = RobotModel.from_urdf()
    assert model.root_link == 'world' and model.base_link == 'base_link'
    assert model.task_axes == (0, 1) and model.joint_names == plain.joint_names
    rng = np.random.default_rng(5)
    for _ in range(4):
        q, qdot = rng.uniform(-2.0, 2.0, 2), rng.normal(size=2)
        kin, ref = model.kinematics(q, qdot), plain.kinematics(q, qdot)
        for name in ('p_W', 'R_W_ee', 'x', 'xdot', 'J_ee', 'Jdot_ee'):
            assert np.allclose(getattr(kin, name), getattr(ref, name), atol=1e-12), name
        # the same point, seen from the URDF root: p_root = R_root_W p_W + t_root_W (W: base_link)
        data = model.model.createData()
        pin.forwardKinematics(model.model, data, q)
        oMf = pin.updateFramePlacement(model.model, data, model.frame_id)
        assert np.allclose(oMf.translation, R_root_W @ ref.p_W + BASE_XYZ, atol=1e-12)
        assert not np.allclose(oMf.translation[:2], ref.x)  # the transform is not trivial
        J_world = pin.computeFrameJacobian(model.model, data, q, model.frame_id,
                                           pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
        assert np.allclose(R_root_W.T @ J_world, np.vstack([ref.J_ee, np.zeros(2)]), atol=1e-12)
        assert np.allclose(model.frame_rotation(q, 'tool0'), plain.frame_rotation(q, 'tool0'))
        # gravity given in the root frame: the same joint-space dynamics
        for a, b in zip(model.joint_terms(q, qdot), plain.joint_terms(q, qdot)):
            assert np.allclose(a, b, atol=1e-9)


def test_closed_loop_with_base_link_different_from_root():
    gravity_root = R_root_W @ np.array([0.0, -9.81, 0.0])
    model = RobotModel.from_urdf(_two_link_on_a_stand(), base_link='base_link',
                                 gravity_root=gravity_root)
    result = run_scenario(ScenarioConfig(q0=PAPER_Q0, duration=8.0, theta_hat0_scale=0.7),
                          model)
    met = compute_metrics(RunLog.from_result(result), t_start=5.0)
    assert met['rms_position_error_m'] <= 2e-4, met
    assert met['rms_force_error_n'] <= 0.02, met
    assert met['contact_lost_s'] == 0.0, met


# --------------------------------------------------------------------------- 6. ROS node
@pytest.fixture
def panda_node(tmp_path):
    args = ['-p', f'robot_description:={panda_urdf_path()}',
            '-p', 'end_effector_link:=panda_hand_tcp',
            '-p', f'joints:=[{",".join(PANDA_JOINTS)}]',
            '-p', 'gravity:=[0.0,0.0,-9.81]', '-p', 'n:=[0.0,0.0,-1.0]']
    proc = NodeProcess(CONTROLLER_MODULE,
                       tmp_path / 'controller.log',
                       DOMAIN_ID, args, params_file=None)
    spun = Spun(DOMAIN_ID)
    try:
        tester = spun.node('any_arm_tester')
        proc.start()
        yield proc, tester
    finally:
        proc.stop()
        spun.close()


@pytest.mark.dds
def test_controller_node_starts_for_the_panda(panda_node):
    from rclpy.parameter import parameter_value_to_python
    from rclpy.parameter_client import AsyncParameterClient
    proc, tester = panda_node
    wait_for(lambda: 'hybrid_force_controller' in tester.get_node_names(),
             'the node in the graph', alive=[proc])
    client = AsyncParameterClient(tester, 'hybrid_force_controller')
    assert client.wait_for_services(timeout_sec=60.0), proc.tail()
    names = ['joints', 'end_effector_link', 'robot_description', 'gravity', 'n']
    values = wait_future(client.get_parameters(names)).values
    got = {k: parameter_value_to_python(v) for k, v in zip(names, values)}
    assert list(got['joints']) == list(PANDA_JOINTS)
    assert got['end_effector_link'] == 'panda_hand_tcp'
    assert got['robot_description'] == str(panda_urdf_path())
    assert np.allclose(got['gravity'], [0.0, 0.0, -9.81])
    assert np.allclose(got['n'], [0.0, 0.0, -1.0])
    # theta_hat is advertised (it publishes only once it has inputs)
    topics = dict(tester.get_publisher_names_and_types_by_node('hybrid_force_controller', '/'))
    assert topics.get('/hybrid_force_controller/theta_hat') == ['std_msgs/msg/Float64MultiArray']
    # one joint state and one wrench: the node computes and publishes 7 finite efforts
    from geometry_msgs.msg import WrenchStamped
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray
    efforts = []
    tester.create_subscription(Float64MultiArray, '/effort_controller/commands',
                               lambda m: efforts.append(list(m.data)), 10)
    pub_js = tester.create_publisher(JointState, '/joint_states', 10)
    pub_f = tester.create_publisher(WrenchStamped, '/force_torque_sensor_broadcaster/wrench', 10)

    def publish_inputs_until_an_effort() -> bool:
        pub_js.publish(JointState(name=list(PANDA_JOINTS), position=list(PANDA_Q0),
                                  velocity=[0.0] * 7))
        wrench = WrenchStamped()
        wrench.header.frame_id = 'panda_hand_tcp'
        pub_f.publish(wrench)
        return bool(efforts)
    wait_for(publish_inputs_until_an_effort, 'a computed effort', alive=[proc], poll=0.05)
    assert len(efforts[-1]) == 7 and np.all(np.isfinite(efforts[-1]))
    assert np.all(np.abs(efforts[-1]) <= np.array([87, 87, 87, 87, 12, 12, 12]) + 1e-9)
