"""
Oracle tests of ``hybrid_force_controller.core.model.robot_model`` (pinocchio path).

* The bundled 2-link arm against the paper's closed form, eqs. (30)-(37) of [1] with the
  errata fixed (``test/closed_form_2link.py``), at random non-singular states.
* Documented relations (skew-symmetry of Mdot - 2C in joint and task space, linearity in
  theta, RNEA / CRBA / Coriolis-matrix consistency) on the 2-link arm and on a 3-DOF
  spatial arm with a full rotational inertia tensor (``test/three_link_spatial.urdf``).
* The printed forms of (32), (33), (35), (36) disagree with the model (errata are real).

Construction and its errors: test_model_construction.py.

[1] Jafari et al., "An Adaptive Hybrid Force/Motion Control Design for Robot Manipulators
Interacting in Constrained Motion with Unknown Non-Rigid Environments".
"""
from __future__ import annotations

from pathlib import Path

import closed_form_2link
from hybrid_force_controller.core.model.robot_model import ModelError, RobotModel
import numpy as np
import pinocchio as pin
import pytest


TEST_DIR = Path(__file__).resolve().parent
SPATIAL_URDF = TEST_DIR / 'three_link_spatial.urdf'


ARM = closed_form_2link.TwoLinkArm()  # l1 = l2 = 1 m, m1 = 1.3 kg, m2 = 0.9 kg, g0 = 9.81

N_STATES = 24
TOL = 1e-9


def _assert_close(actual, expected, tol=TOL, what=''):
    """Assert ``|actual - expected|_max <= tol * max(1, |expected|_max)``."""
    actual, expected = np.asarray(actual, dtype=float), np.asarray(expected, dtype=float)
    assert actual.shape == expected.shape, f'{what}: shape {actual.shape} != {expected.shape}'
    scale = max(1.0, float(np.max(np.abs(expected))))
    err = float(np.max(np.abs(actual - expected)))
    assert err <= tol * scale, f'{what}: max error {err:.3e} > {tol:.1e} * {scale:.3g}'


def _assert_skew(S, tol, what=''):
    """Assert that ``S + S^T`` vanishes relative to ``max(1, |S|_max)``."""
    scale = max(1.0, float(np.max(np.abs(S))))
    err = float(np.max(np.abs(S + S.T)))
    assert err <= tol * scale, f'{what}: |S + S^T|_max = {err:.3e} (scale {scale:.3g})'


def _states_2link(n, seed):
    """Random states (q, qdot, r, rdot) of the 2-link arm with ``|sin q2| > 0.2``."""
    rng = np.random.default_rng(seed)
    states = []
    while len(states) < n:
        q = rng.uniform(-np.pi, np.pi, 2)
        if abs(np.sin(q[1])) <= 0.2:
            continue
        states.append((q, rng.uniform(-2.0, 2.0, 2), rng.uniform(-1.0, 1.0, 2),
                       rng.uniform(-3.0, 3.0, 2)))
    return states


def _states_model(model, n, seed, max_cond=30.0):
    """Random states (q, qdot, r, rdot) of ``model`` whose task Jacobian is well conditioned."""
    rng = np.random.default_rng(seed)
    states = []
    while len(states) < n:
        q = rng.uniform(-np.pi, np.pi, model.n)
        qdot = rng.uniform(-2.0, 2.0, model.n)
        if np.linalg.cond(model.kinematics(q, qdot).J_ee) > max_cond:
            continue
        states.append((q, qdot, rng.uniform(-1.0, 1.0, model.m), rng.uniform(-3.0, 3.0, model.m)))
    return states


STATES_2LINK = _states_2link(N_STATES, seed=20240601)


@pytest.fixture(scope='module')
def arm2():
    """Load the bundled 2-link arm of section V of [1]."""
    return RobotModel.from_urdf()


@pytest.fixture(scope='module')
def arm3():
    """Load the 3-DOF spatial test arm (square 3x3 task Jacobian)."""
    return RobotModel.from_urdf(SPATIAL_URDF)


@pytest.fixture(scope='module', params=['two_link', 'three_link_spatial'])
def arm_and_states(request):
    """Each test arm with its own fixed-seed random states."""
    if request.param == 'two_link':
        model = RobotModel.from_urdf()
        return model, STATES_2LINK
    model = RobotModel.from_urdf(SPATIAL_URDF)
    return model, _states_model(model, N_STATES, seed=7)


# ---------------------------------------------------------------- set-up of the bundled arm
def test_bundled_arm_parameters(arm2):
    """The bundled URDF is the paper's arm: theta = [m1, m2] = [1.3, 0.9], planar x-y task."""
    assert arm2.n == 2 and arm2.m == 2
    assert arm2.task_axes == (0, 1)
    assert arm2.joint_names == ('joint1', 'joint2')
    np.testing.assert_allclose(arm2.theta_nominal, ARM.theta, rtol=0, atol=1e-12)
    np.testing.assert_allclose(arm2.model.gravity.linear, [0.0, -ARM.g0, 0.0])


# ---------------------------------------------------------------- 2-link vs closed form
@pytest.mark.parametrize('k', range(N_STATES))
def test_kinematics_matches_closed_form(arm2, k):
    """x, xdot, J, Jdot of the pinocchio path equal eqs. (30)-(31) and d/dt (31)."""
    q, qdot, _, _ = STATES_2LINK[k]
    kin = arm2.kinematics(q, qdot)
    _assert_close(kin.x, ARM.fk(q), what='x (30)')
    _assert_close(kin.p_W, np.append(ARM.fk(q), 0.0), what='p_W')
    _assert_close(kin.J_ee, ARM.jacobian(q), what='J (31)')
    _assert_close(kin.Jdot_ee, ARM.jacobian_dot(q, qdot), what='Jdot')
    _assert_close(kin.xdot, ARM.jacobian(q) @ qdot, what='xdot')


@pytest.mark.parametrize('k', range(N_STATES))
def test_joint_terms_match_closed_form(arm2, k):
    """M, C, g equal the corrected eqs. (32)-(34)."""
    q, qdot, _, _ = STATES_2LINK[k]
    M, C, g = arm2.joint_terms(q, qdot)
    _assert_close(M, ARM.mass_matrix(q), what='M (32)')
    _assert_close(C, ARM.coriolis(q, qdot), what='C (33)')
    _assert_close(g, ARM.gravity(q), what='g (34)')


@pytest.mark.parametrize('k', range(N_STATES))
def test_task_terms_match_closed_form(arm2, k):
    """M_x, C_x, g_x equal the corrected eqs. (35)-(37)."""
    q, qdot, _, _ = STATES_2LINK[k]
    M_x, C_x, g_x = arm2.task_terms(q, qdot)
    M_x_cf, C_x_cf, g_x_cf = ARM.task_terms(q, qdot)
    _assert_close(M_x, M_x_cf, what='M_x (35)')
    _assert_close(C_x, C_x_cf, what='C_x (36)')
    _assert_close(g_x, g_x_cf, what='g_x (37)')


@pytest.mark.parametrize('k', range(N_STATES))
def test_regressors_match_closed_form(arm2, k):
    """Y_q, Y_x and Y_x theta equal the hand-derived regressor for theta = [m1, m2]."""
    q, qdot, r, rdot = STATES_2LINK[k]
    kin = arm2.kinematics(q, qdot)
    qdot_r = np.linalg.solve(kin.J_ee, r)
    qddot_r = np.linalg.solve(kin.J_ee, rdot - kin.Jdot_ee @ qdot_r)
    _assert_close(arm2.regressor_q(q, qdot, qdot_r, qddot_r),
                  ARM.regressor_q(q, qdot, qdot_r, qddot_r), what='Y_q')
    Y_x = arm2.regressor_x(q, qdot, r, rdot)
    _assert_close(Y_x, ARM.regressor_x(q, qdot, r, rdot), what='Y_x')
    M_x, C_x, g_x = ARM.task_terms(q, qdot)
    _assert_close(Y_x @ ARM.theta, M_x @ rdot + C_x @ r + g_x, what='Y_x theta')


def _regressor_three_calls(model, q, v, w, a):
    """Return the Slotine-Li regressor [R(v+w, 4a) - R(v-w, 0)]/4 + R(0, 0): three RNEA calls."""
    def R(v_, a_):
        return pin.computeJointTorqueRegressor(model.model, model.model.createData(), q, v_, a_)
    z = np.zeros(model.n)
    R3 = 0.25 * (R(v + w, 4.0 * a) - R(v - w, z)) + R(z, z)
    return R3 @ model.parameter_set.P, R3 @ model.parameter_set.pi_0


@pytest.mark.parametrize('arm,parameter_set', [('two_link', 'link_masses'), ('two_link', 'full'),
                                               ('panda', 'link_masses'), ('panda', 'payload')])
def test_two_call_regressor_equals_three_call_form(arm, parameter_set):
    """(R2) of regressor_affine equals the 3-call polarisation form to 1e-12 at random states."""
    from hybrid_force_controller.core.offline.arm7 import panda_model
    model = (RobotModel.from_urdf(parameter_set=parameter_set) if arm == 'two_link'
             else panda_model(parameter_set))
    rng = np.random.default_rng(5)
    for _ in range(20):
        q, v, w, a = (rng.uniform(-2.0, 2.0, model.n) for _ in range(4))
        Y, tau_0 = model.regressor_affine(q, v, w, a)
        Y3, tau_03 = _regressor_three_calls(model, q, v, w, a)
        _assert_close(Y, Y3, tol=1e-12, what='Y_q')
        _assert_close(0.0 * tau_03 if tau_0 is None else tau_0, tau_03, tol=1e-12, what='tau_0')


def test_closed_form_regressor_is_consistent():
    """The hand-derived Y_x theta equals M_x rdot + C_x r + g_x of the closed form itself."""
    for q, qdot, r, rdot in STATES_2LINK:
        M_x, C_x, g_x = ARM.task_terms(q, qdot)
        _assert_close(ARM.regressor_x(q, qdot, r, rdot) @ ARM.theta,
                      M_x @ rdot + C_x @ r + g_x, what='closed-form Y_x theta')


def test_jacobian_dot_matches_finite_difference_2link():
    """Closed-form Jdot equals a central difference of J along qdot (oracle self-check)."""
    h = 1e-6
    for q, qdot, _, _ in STATES_2LINK:
        fd = (ARM.jacobian(q + h * qdot) - ARM.jacobian(q - h * qdot)) / (2.0 * h)
        _assert_close(ARM.jacobian_dot(q, qdot), fd, tol=1e-6, what='closed-form Jdot vs FD')


# ---------------------------------------------------------------- relations, both arms
def test_jacobian_dot_matches_finite_difference(arm_and_states):
    """Jdot of the model equals (J(q + h qdot) - J(q - h qdot)) / 2h."""
    model, states = arm_and_states
    h = 1e-6
    for q, qdot, _, _ in states:
        kin = model.kinematics(q, qdot)
        fd = (model.kinematics(q + h * qdot, qdot).J_ee
              - model.kinematics(q - h * qdot, qdot).J_ee) / (2.0 * h)
        _assert_close(kin.Jdot_ee, fd, tol=1e-6, what='Jdot vs FD')
        _assert_close(kin.xdot, kin.J_ee @ qdot, what='xdot = J qdot')


@pytest.mark.parametrize('terms', ['task_terms', 'joint_terms'])
def test_skew_symmetry(arm_and_states, terms):
    """
    Check that Mdot - 2 C is skew-symmetric, eq. (3), in task and joint space.

    In task space (M_x, C_x) and in joint space (Mdot by central difference along qdot).
    """
    model, states = arm_and_states
    inertia_and_coriolis = getattr(model, terms)
    h = 1e-6
    for q, qdot, _, _ in states:
        M_p = inertia_and_coriolis(q + h * qdot, qdot)[0]
        M_m = inertia_and_coriolis(q - h * qdot, qdot)[0]
        _, C, _ = inertia_and_coriolis(q, qdot)
        _assert_skew((M_p - M_m) / (2.0 * h) - 2.0 * C, tol=1e-5, what=f'Mdot - 2 C ({terms})')


def test_task_regressor_is_linear_in_theta(arm_and_states):
    """Y_x theta = M_x a + C_x v + g_x, eq. (4), at nominal and at random theta."""
    model, states = arm_and_states
    rng = np.random.default_rng(11)
    for q, qdot, v, a in states:
        Y_x = model.regressor_x(q, qdot, v, a)
        assert Y_x.shape == (model.m, len(model.theta_nominal))
        for theta in (model.theta_nominal, rng.uniform(0.2, 3.0, len(model.theta_nominal))):
            M_x, C_x, g_x = model.task_terms(q, qdot, theta)
            _assert_close(Y_x @ theta, M_x @ a + C_x @ v + g_x, what='Y_x theta')


def test_coriolis_times_qdot_matches_rnea(arm_and_states):
    """C(q, qdot) qdot = rnea(q, qdot, 0) - g(q) (pinocchio called directly)."""
    model, states = arm_and_states
    zero = np.zeros(model.n)
    for q, qdot, _, _ in states:
        _, C, g = model.joint_terms(q, qdot)
        tau_v = pin.rnea(model.model, model.data, q, qdot, zero).copy()
        g_pin = pin.computeGeneralizedGravity(model.model, model.data, q).copy()
        _assert_close(g, g_pin, what='g vs computeGeneralizedGravity')
        _assert_close(C @ qdot, tau_v - g_pin, what='C qdot vs rnea')


def test_coriolis_matrix_matches_pinocchio(arm_and_states):
    """The Christoffel C equals pinocchio's computeCoriolisMatrix."""
    model, states = arm_and_states
    for q, qdot, _, _ in states:
        C_pin = pin.computeCoriolisMatrix(model.model, model.data, q, qdot).copy()
        _assert_close(model.joint_terms(q, qdot)[1], C_pin, what='C vs computeCoriolisMatrix')


def test_mass_matrix_matches_crba(arm_and_states):
    """M equals pinocchio's CRBA (upper triangle symmetrised)."""
    model, states = arm_and_states
    for q, qdot, _, _ in states:
        M_pin = np.triu(pin.crba(model.model, model.data, q))
        M_pin = M_pin + np.triu(M_pin, 1).T
        M = model.joint_terms(q, qdot)[0]
        _assert_close(M, M_pin, what='M vs crba')
        assert np.all(np.linalg.eigvalsh(M) > 0.0)


def test_task_inertia_is_symmetric_positive_definite(arm_and_states):
    """M_x = J^-T M J^-1 is symmetric positive definite."""
    model, states = arm_and_states
    for q, qdot, _, _ in states:
        M_x = model.task_terms(q, qdot)[0]
        _assert_close(M_x, M_x.T, what='M_x symmetric')
        assert np.all(np.linalg.eigvalsh(0.5 * (M_x + M_x.T)) > 0.0)


def test_forward_dynamics_inverts_rnea(arm_and_states):
    """ABA(q, qdot, rnea(q, qdot, a)) = a."""
    model, states = arm_and_states
    rng = np.random.default_rng(3)
    for q, qdot, _, _ in states:
        a = rng.uniform(-2.0, 2.0, model.n)
        tau = pin.rnea(model.model, model.data, q, qdot, a).copy()
        _assert_close(model.forward_dynamics(q, qdot, tau), a, tol=1e-8, what='aba(rnea)')


def test_spatial_arm_is_square_3d(arm3):
    """The spatial test arm has a 3-D task space, 3 joints and theta = its 3 link masses."""
    assert arm3.n == 3 and arm3.m == 3 and arm3.task_axes == (0, 1, 2)
    np.testing.assert_allclose(arm3.theta_nominal, [1.2, 0.9, 0.6])


# ---------------------------------------------------------------- errata are real
def _errata_states():
    """2-link states where every printed typo has a clearly non-zero effect."""
    return [s for s in STATES_2LINK
            if abs(np.cos(s[0][1])) > 0.2 and abs(s[1][0] ** 2 - s[1][1] ** 2) > 0.1]


def test_errata_states_available():
    """Enough states exercise the typos."""
    assert len(_errata_states()) >= 5


def test_eq32_as_printed_disagrees(arm2):
    """Printed (32) M12 exceeds pinocchio's by exactly m2 l1 l2 cos q2."""
    for q, qdot, _, _ in _errata_states():
        M = arm2.joint_terms(q, qdot)[0]
        M_printed = ARM.mass_matrix_as_printed(q)
        offset = ARM.m2 * ARM.l1 * ARM.l2 * np.cos(q[1])
        assert abs(M_printed[0, 1] - M[0, 1]) > 0.1
        _assert_close(M_printed - M, offset * np.array([[0.0, 1.0], [1.0, 0.0]]),
                      what='printed M - M')


def test_eq33_as_printed_disagrees(arm2):
    """Printed (33): row 2 of C_q qdot is wrong and Mdot - 2 C_q is not skew-symmetric."""
    h = 1e-6
    for q, qdot, _, _ in _errata_states():
        C_printed = ARM.coriolis_as_printed(q, qdot)
        tau_v = pin.rnea(arm2.model, arm2.data, q, qdot, np.zeros(2)).copy()
        tau_v -= pin.computeGeneralizedGravity(arm2.model, arm2.data, q)
        # Row 1 of the printed matrix is a valid (non-Christoffel) factorisation ...
        assert abs((C_printed @ qdot)[0] - tau_v[0]) < 1e-9
        # ... row 2 gives m2 l1 l2 sin q2 qdot2^2 instead of m2 l1 l2 sin q2 qdot1^2.
        expected_err = ARM.m2 * ARM.l1 * ARM.l2 * np.sin(q[1]) * (qdot[1] ** 2 - qdot[0] ** 2)
        assert abs((C_printed @ qdot)[1] - tau_v[1] - expected_err) < 1e-9
        assert abs(expected_err) > 0.01
        C_pin = pin.computeCoriolisMatrix(arm2.model, arm2.data, q, qdot)
        assert np.max(np.abs(C_printed - C_pin)) > 0.01
        Mdot = (arm2.joint_terms(q + h * qdot, qdot)[0]
                - arm2.joint_terms(q - h * qdot, qdot)[0]) / (2.0 * h)
        S = Mdot - 2.0 * C_printed
        assert np.max(np.abs(S + S.T)) > 0.01


def test_eq35_as_printed_disagrees(arm2):
    """Printed (35) J^T M J^-1 differs from M_x = J^-T M J^-1 (and is not symmetric)."""
    n_asym = 0
    for q, qdot, _, _ in STATES_2LINK:
        M_x = arm2.task_terms(q, qdot)[0]
        M_x_printed = ARM.task_inertia_as_printed(q)
        assert np.max(np.abs(M_x_printed - M_x)) > 1e-3
        n_asym += np.max(np.abs(M_x_printed - M_x_printed.T)) > 1e-3
    assert n_asym >= N_STATES // 2


def test_eq36_as_printed_disagrees(arm2):
    """Printed (36) ending in J differs from C_x = J^-T (C - M J^-1 Jdot) J^-1."""
    for q, qdot, _, _ in STATES_2LINK:
        C_x = arm2.task_terms(q, qdot)[1]
        C_x_printed = ARM.task_coriolis_as_printed(q, qdot)
        assert np.max(np.abs(C_x_printed - C_x)) > 1e-3 * max(1.0, np.max(np.abs(C_x)))


# ---------------------------------------------------------------- with_theta
def test_with_theta_matches_closed_form(arm2):
    """with_theta([2.0, 0.5]) gives the closed-form M, g (and task terms) at those masses."""
    variant = arm2.with_theta([2.0, 0.5])
    arm_v = closed_form_2link.TwoLinkArm(m1=2.0, m2=0.5)
    np.testing.assert_allclose(variant.theta_nominal, [2.0, 0.5])
    for q, qdot, r, rdot in STATES_2LINK:
        M, C, g = variant.joint_terms(q, qdot)
        _assert_close(M, arm_v.mass_matrix(q), what='M at theta')
        _assert_close(C, arm_v.coriolis(q, qdot), what='C at theta')
        _assert_close(g, arm_v.gravity(q), what='g at theta')
        for a, b in zip(variant.task_terms(q, qdot), arm_v.task_terms(q, qdot)):
            _assert_close(a, b, what='task terms at theta')
        # Same geometry: the regressor is unchanged, and the nominal model's terms at
        # theta = [2.0, 0.5] equal the variant's.
        _assert_close(variant.regressor_x(q, qdot, r, rdot), arm2.regressor_x(q, qdot, r, rdot),
                      what='Y_x unchanged')
        _assert_close(arm2.joint_terms(q, qdot, [2.0, 0.5])[0], M, what='M(theta)')
    # The original model is untouched.
    q = STATES_2LINK[0][0]
    _assert_close(arm2.joint_terms(q, np.zeros(2))[0], ARM.mass_matrix(q), what='original M')


def test_with_theta_rejects_bad_theta(arm2):
    """Wrong length or non-positive masses: ModelError."""
    with pytest.raises(ModelError):
        arm2.with_theta([1.0, 2.0, 3.0])
    with pytest.raises(ModelError):
        arm2.with_theta([1.0, -0.5])
