"""
The law with a moving normal (law/moving_normal.py): the projection (M1) and r, rdot (M2).

Pure numpy + pinocchio, no ROS: the paper's 2-link arm (a planar task) and the Panda (3-D).
(M2) must be the frozen law when n_hat = n does not move, and the exact time derivative of
the r it computes when n_hat turns, the reference is carried along and the force follows the
model the law assumes (``n^T fdot = k_s n^T xdot``, ``hdot = n^T f - f_d``).
"""
from __future__ import annotations

import math

from hybrid_force_controller.core.config.params import build_params
from hybrid_force_controller.core.law.control_law import HybridForceController
from hybrid_force_controller.core.law.moving_normal import MovingNormal, project_rows
from hybrid_force_controller.core.law.reference import Reference
from hybrid_force_controller.core.model.robot_model import RobotModel, TaskKinematics
from hybrid_force_controller.core.offline.arm7 import panda_model
import numpy as np
import pytest


@pytest.fixture(scope='module', params=['paper', 'panda'])
def arm(request) -> tuple[RobotModel, np.ndarray]:
    """Return the model and its told normal n_p."""
    if request.param == 'paper':
        return RobotModel.from_urdf(), np.array([0.0, -1.0, 0.0])
    return panda_model(), np.array([0.0, 0.0, -1.0])


def turned(n_p: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Return ``n_p`` turned by ``angle`` about the unit ``axis`` (Rodrigues)."""
    a = axis / np.linalg.norm(axis)
    return (n_p * math.cos(angle) + np.cross(a, n_p) * math.sin(angle)
            + a * (a @ n_p) * (1.0 - math.cos(angle)))


def in_plane_axis(n_p: np.ndarray) -> np.ndarray:
    """Return an axis that turns n_p within the task space (z for the planar arm)."""
    return np.array([0.0, 0.0, 1.0]) if n_p[2] == 0.0 else np.array([1.0, 0.3, 0.0])


def moving(n_W: np.ndarray, ndot_W: np.ndarray, n_p: np.ndarray, model: RobotModel
           ) -> MovingNormal:
    axes = list(model.task_axes)
    return MovingNormal(tuple(n_W.tolist()), tuple(ndot_W.tolist()), tuple(n_p.tolist()),
                        1.0 / float(n_W @ n_p), None if axes == [0, 1, 2] else axes)


def kin_at(x_W: np.ndarray, xdot_W: np.ndarray, model: RobotModel) -> TaskKinematics:
    ax = list(model.task_axes)
    z = np.zeros((len(ax), model.n))
    return TaskKinematics(x_W, np.eye(3), x_W[ax], xdot_W[ax], z, z)


def projected(rows_W: np.ndarray, x_W: np.ndarray, n_W: np.ndarray, n_p: np.ndarray
              ) -> tuple[Reference, list]:
    kq = (n_p / float(n_W @ n_p)).tolist()
    rows = project_rows(rows_W, x_W, n_W.tolist(), kq)
    a = np.array(rows)
    return Reference(a[0], a[1], a[2]), rows


def test_the_projection_keeps_the_path_plane_and_lands_on_n_hats_tangent_plane(arm):
    model, n_p = arm
    n = turned(n_p, in_plane_axis(n_p), 0.3)
    rng = np.random.default_rng(3)
    rows = rng.normal(size=(3, 3))
    if n_p[2] == 0.0:
        rows[:, 2] = 0.0
    x = rng.normal(size=3) * (n_p[2] != 0.0) + np.array([0.8, 1.6, 0.0])
    ref, _ = projected(rows, x, n, n_p)
    # (M1): nothing along n_hat (the position relative to the tool) ...
    assert abs(n @ (ref.x_d_W - x)) < 1e-12
    assert abs(n @ ref.xdot_d_W) < 1e-12 and abs(n @ ref.xddot_d_W) < 1e-12
    # ... and moved only along n_p: the same point of the path's own plane
    P_p = np.eye(3) - np.outer(n_p, n_p)
    for new, old in zip(ref, rows):
        np.testing.assert_allclose(P_p @ new, P_p @ old, atol=1e-12)


def test_with_n_hat_equal_to_n_and_at_rest_it_is_the_frozen_law(arm):
    model, n_p = arm
    params = build_params(model, {'n': n_p.tolist()})
    frozen, direct = (HybridForceController(model, params.law) for _ in range(2))
    direct.set_normal(moving(n_p, np.zeros(3), n_p, model))
    rng = np.random.default_rng(7)
    for _ in range(5):
        x = np.array([0.8, 1.6, 0.4]) + 0.01 * rng.normal(size=3)
        xdot, rows = rng.normal(size=3), rng.normal(size=(3, 3))
        if n_p[2] == 0.0:
            x[2] = xdot[2] = rows[:, 2] = 0.0
        kin = kin_at(x, xdot, model)
        ref, _ = projected(rows, x, n_p, n_p)
        f = (1.3 * n_p + 0.2 * rng.normal(size=3))[list(model.task_axes)]
        for c in (frozen, direct):
            c.h = 0.01
        a, b = (c.reference_velocity(kin, ref, f) for c in (frozen, direct))
        for u, v in zip(a, b):
            np.testing.assert_allclose(v, u, rtol=1e-12, atol=1e-12)


def state_at(model: RobotModel, n_p: np.ndarray, t: float, k_s: float) -> dict:
    """
    Return a smooth run at ``t``: n_hat turning at 0.4 rad/s, the tool and reference moving.

    The force is a spring ``k_s (x - x0)`` in every direction plus 1 N along n_hat, so
    ``n^T fdot = k_s n^T xdot`` up to the turning (the model of eq. (11)).
    """
    axis, planar = in_plane_axis(n_p), n_p[2] == 0.0
    n = turned(n_p, axis, 0.25 + 0.4 * t)
    ndot = (turned(n_p, axis, 0.25 + 0.4 * (t + 1e-7))
            - turned(n_p, axis, 0.25 + 0.4 * (t - 1e-7))) / 2e-7
    z = 0.0 if planar else 1.0
    e = np.array([1.0, 0.5, 0.7 * z])
    x0 = np.array([0.8, 1.6, 0.4 * z])
    x, xdot = x0 + 0.01 * np.sin(3.0 * t) * e, 0.03 * np.cos(3.0 * t) * e
    p = x0 + np.array([0.01 + 0.05 * np.sin(t), -0.01 + 0.02 * t * t, 0.01 * z + 0.03 * z * t])
    pdot = np.array([0.05 * np.cos(t), 0.04 * t, 0.03 * z])
    pddot = np.array([-0.05 * np.sin(t), 0.04, 0.0])
    ref, _ = projected(np.array([p, pdot, pddot]), x, n, n_p)
    f_W = k_s * (x - x0) + 1.0 * n
    return {'n': n, 'ndot': ndot, 'kin': kin_at(x, xdot, model), 'ref': ref,
            'f': f_W[list(model.task_axes)], 'f_n': float(n @ f_W)}


def law_r(ctrl: HybridForceController, model: RobotModel, n_p: np.ndarray, s: dict, h: float,
          ndot: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Return r and the law's rdot in the state ``s`` with the force integral ``h``."""
    ctrl.set_normal(moving(s['n'], s['ndot'] if ndot else np.zeros(3), n_p, model))
    ctrl.h = h
    return ctrl.reference_velocity(s['kin'], s['ref'], s['f'])[:2]


def test_rdot_is_the_derivative_of_r_with_the_normal_turning(arm):
    """(M2): the dS/dt terms fed forward make rdot the derivative of r (design.md, (N7))."""
    model, n_p = arm
    ctrl = HybridForceController(model, build_params(model, {'n': n_p.tolist(),
                                                             'f_d': 2.0}).law)
    t, eps, h = 0.7, 1e-5, 0.003
    now = state_at(model, n_p, t, ctrl.k_s)
    hdot = now['f_n'] - ctrl.f_d  # (20)
    r_plus = law_r(ctrl, model, n_p, state_at(model, n_p, t + eps, ctrl.k_s), h + eps * hdot)[0]
    r_minus = law_r(ctrl, model, n_p, state_at(model, n_p, t - eps, ctrl.k_s),
                    h - eps * hdot)[0]
    numeric = (r_plus - r_minus) / (2.0 * eps)
    rdot = law_r(ctrl, model, n_p, now, h)[1]
    np.testing.assert_allclose(rdot, numeric, rtol=1e-5, atol=1e-7)
    # the terms in ndot matter: without them rdot misses the derivative by far more
    rdot_frozen = law_r(ctrl, model, n_p, now, h, ndot=False)[1]
    assert np.linalg.norm(rdot_frozen - numeric) > 1e-3
    assert np.linalg.norm(rdot_frozen - numeric) > 1e3 * np.linalg.norm(rdot - numeric)


def test_the_normal_in_use_and_back_to_the_gains(arm):
    model, n_p = arm
    ctrl = HybridForceController(model, build_params(model, {'n': n_p.tolist()}).law)
    n = turned(n_p, in_plane_axis(n_p), 0.2)
    ctrl.set_normal(moving(n, np.zeros(3), n_p, model))
    np.testing.assert_allclose(ctrl.n, n[list(model.task_axes)])
    ctrl.set_normal(None)
    assert ctrl.n is ctrl._d.n
