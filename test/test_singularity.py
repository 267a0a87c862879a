"""
Near a singularity (linalg.damped_inverse, control_law.py): bounded, and theta_hat holds.

The paper's arm reaches full extension at |x| = 2 m; its sine ends 5 cm short (the smallest
singular value of J there is 0.21 m). A fault that leaves the arm or the reference beyond it
made J^-1 grow without bound: theta_hat went bang-bang between its projection bounds and the
arm flailed (1.4 kN on the surface, CI of 2026-12-03). Offline, no ROS.
"""
from __future__ import annotations

from hybrid_force_controller.core.config.params import build_params
from hybrid_force_controller.core.law.control_law import HybridForceController
from hybrid_force_controller.core.law.reference import Reference
from hybrid_force_controller.core.law.task_inverse import redundant_inverse
from hybrid_force_controller.core.model.linalg import (damped_inverse, sigma_min_sq,
                                                       sigma_min_sq_bound, small_inverse)
from hybrid_force_controller.core.model.robot_model import RobotModel
import numpy as np
import pytest


SIGMA0 = 0.1  # singular_sigma's default, m


def _matrices(seed: int = 0):
    """Random square matrices, some of them near singular (one singular value scaled down)."""
    rng = np.random.default_rng(seed)
    for n in (2, 3):
        for scale in (1.0, 0.3, 0.05, 1e-4):
            U, _, Vt = np.linalg.svd(rng.normal(size=(n, n)))
            s = np.sort(rng.uniform(0.5, 2.0, n))[::-1]
            s[-1] *= scale
            yield (U * s) @ Vt


def test_sigma_min_sq_matches_the_svd():
    for J in _matrices():
        expected = np.linalg.svd(J, compute_uv=False)[-1] ** 2
        assert sigma_min_sq(J) == pytest.approx(expected, rel=1e-9, abs=1e-15)


def test_the_damped_inverse_is_the_inverse_away_from_a_singularity_and_bounded_near_one():
    """J^-1 while sigma >= sigma0, else J^T (J J^T + (s0^2 - s^2) I)^-1: a gain <= 1/sigma0."""
    for J in _matrices():
        inv, damped = damped_inverse(J, SIGMA0)
        sigma = np.linalg.svd(J, compute_uv=False)[-1]
        assert damped is bool(sigma < SIGMA0)
        if not damped:
            np.testing.assert_allclose(inv, small_inverse(J), rtol=1e-12)
            continue
        mu2 = SIGMA0 ** 2 - sigma ** 2
        np.testing.assert_allclose(inv, J.T @ np.linalg.inv(J @ J.T + mu2 * np.eye(len(J))),
                                   rtol=1e-9, atol=1e-12)
        assert np.linalg.norm(inv, 2) <= 1.0 / SIGMA0 + 1e-9
    J = np.diag([1.0, SIGMA0 * (1.0 + 1e-9)])  # continuous at sigma = sigma0
    np.testing.assert_allclose(damped_inverse(J * (1.0 - 2e-9), SIGMA0)[0], small_inverse(J),
                               rtol=1e-6)
    with pytest.raises(np.linalg.LinAlgError):  # off: a singular J is not inverted
        damped_inverse(np.diag([1.0, 0.0]), 0.0)


def _ik(x: float, y: float) -> np.ndarray:
    """Return the elbow-down joint angles of the paper's arm (1 m links) at (x, y)."""
    c2 = (x * x + y * y - 2.0) / 2.0
    q2 = float(np.arccos(np.clip(c2, -1.0, 1.0)))
    return np.array([np.arctan2(y, x) - np.arctan2(np.sin(q2), 1.0 + np.cos(q2)), q2])


@pytest.mark.parametrize('x,damped', [(1.0, False), (1.1, False), (1.19, True)])
def test_the_law_holds_theta_hat_and_bounds_the_effort_near_full_reach(x, damped):
    """
    One step with a 0.5 m/s tracking error; at x = 1.19 m (sigma 0.069) damped and held.

    The effort stays within 2 times the one at 1.1 m; away from the singularity the step is
    the plain law's (singular_sigma 0 gives the same effort and theta_hat).
    """
    model = RobotModel.from_urdf()
    q, qdot = _ik(x, 1.6), np.zeros(2)
    ref = Reference(np.array([x, 1.6, 0.0]), np.array([0.5, 0.0, 0.0]), np.zeros(3))
    out = {}
    for sigma0 in (SIGMA0, 0.0):
        ctrl = HybridForceController(model, build_params(model, {'singular_sigma': sigma0}).law)
        theta0 = ctrl.theta_hat.copy()
        o = ctrl.step(q, qdot, np.array([0.0, -1.0, 0.0]), ref, 1e-3)
        out[sigma0] = (o.tau, ctrl.theta_hat - theta0, ctrl.damped)
    tau, dtheta, was_damped = out[SIGMA0]
    assert was_damped is damped
    if damped:
        assert not dtheta.any()
        assert np.abs(tau).max() < np.abs(out[0.0][0]).max()  # the plain inverse: larger
    else:
        np.testing.assert_array_equal(tau, out[0.0][0])
        np.testing.assert_array_equal(dtheta, out[0.0][1])
        assert dtheta.any()


# ------------------------------------------------------------ the redundant 6-D task's inverse
@pytest.mark.parametrize('seed', range(4))
def test_the_redundant_inverse_inverts_j_and_is_damped_below_sigma0(seed):
    """
    task_inverse.py: above sigma0 ``J Jbar = I`` and ``J N = 0``; below it damped and bounded.

    J is 6 x 7 with its smallest singular value 1.0, 0.3, 0.05, 1e-4 (seeds 0-3), M a random
    symmetric positive definite inertia.
    """
    rng = np.random.default_rng(seed)
    U, _, Vt = np.linalg.svd(rng.normal(size=(6, 7)))
    s = np.linspace(2.0, 1.0, 6)
    s[-1] = (1.0, 0.3, 0.05, 1e-4)[seed]
    J = U @ np.hstack((np.diag(s), np.zeros((6, 1)))) @ Vt
    B = rng.normal(size=(7, 7))
    M_inv = np.linalg.inv(B @ B.T + 0.5 * np.eye(7))
    J_pinv, N, damped = redundant_inverse(M_inv, J, SIGMA0, np.eye(7))
    assert damped == (sigma_min_sq_bound(J) < SIGMA0 ** 2) == (seed >= 2)
    assert np.all(np.isfinite(J_pinv)) and np.all(np.isfinite(N))
    if not damped:
        np.testing.assert_allclose(J @ J_pinv, np.eye(6), atol=1e-9)
        np.testing.assert_allclose(J @ N, 0.0, atol=1e-9)
    else:
        assert np.abs(J @ J_pinv - np.eye(6)).max() > 1e-3  # damped: not the exact inverse
        assert np.linalg.norm(J_pinv, 2) < 1e3  # bounded, where the exact one grows as 1/s
