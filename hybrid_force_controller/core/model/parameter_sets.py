"""
Adaptive parameter sets theta, all mapped onto pinocchio's inertial parameters.

Pinocchio's ``computeJointTorqueRegressor`` is linear in the 10 inertial parameters of every
body, ``pi_j = [m, m c, I_xx, I_xy, I_yy, I_xz, I_yz, I_zz]`` (inertia about the joint
origin). Each set is an affine map ``pi = P theta + pi_0`` (``pi_0``: the part that is
known), so eq. (4) of [1] holds as ``Y_q theta + R pi_0`` for any set:

- ``link_masses`` (the paper's set): one mass per link with mass; each link keeps its
  nominal geometry, ``pi_j = theta_j pi_j_nominal / m_j_nominal``.
- ``payload``: the 10 inertial parameters of an unknown load rigidly attached to the body
  that carries the end effector, expressed in that body's joint frame; the arm itself is
  the URDF's (``pi_0``).
- ``full``: all 10 parameters of every body; after each adaptation step the estimate is
  projected onto physically consistent values (mass >= ``min_mass``, inertia about the
  centre of mass positive definite and satisfying the triangle inequalities).

Pure numpy + pinocchio.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import pinocchio as pin

__all__ = ['PARAMETER_SETS', 'ParameterSet', 'ParameterSetError', 'make_parameter_set',
           'project_physical']

PARAMETER_SETS = ('link_masses', 'payload', 'full')


class ParameterSetError(ValueError):
    """Unknown parameter set, or a model it cannot be built for."""


_NAMES10 = ('m', 'mcx', 'mcy', 'mcz', 'Ixx', 'Ixy', 'Iyy', 'Ixz', 'Iyz', 'Izz')


@dataclass(frozen=True)
class ParameterSet:
    """``pi = P theta + pi_0`` with names, nominal values, default bounds and projection."""

    name: str
    P: np.ndarray
    pi_0: np.ndarray
    theta_names: tuple[str, ...]
    theta_nominal: np.ndarray
    theta_min: np.ndarray
    theta_max: np.ndarray
    project: Callable[[np.ndarray], np.ndarray] | None = None


def _pi(model: pin.Model) -> np.ndarray:
    return np.concatenate([model.inertias[j].toDynamicParameters()
                           for j in range(1, model.njoints)])


def _link_masses(model: pin.Model, ee_joint: int) -> ParameterSet:
    cols, names, masses = [], [], []
    nb = model.njoints - 1
    for j in range(1, model.njoints):
        inertia = model.inertias[j]
        if inertia.mass <= 0.0:
            continue
        col = np.zeros(10 * nb)
        col[10 * (j - 1):10 * j] = inertia.toDynamicParameters() / inertia.mass
        cols.append(col)
        names.append(f'm_{model.names[j]}')
        masses.append(inertia.mass)
    if not cols:
        raise ParameterSetError('no link carries mass: nothing to adapt')
    m = np.array(masses)
    return ParameterSet('link_masses', np.column_stack(cols), np.zeros(10 * nb), tuple(names),
                        m, np.zeros_like(m), 10.0 * m)


def _payload(model: pin.Model, ee_joint: int) -> ParameterSet:
    nb = model.njoints - 1
    P = np.zeros((10 * nb, 10))
    P[10 * (ee_joint - 1):10 * ee_joint, :] = np.eye(10)
    big = np.array([20.0, 5.0, 5.0, 5.0, 2.0, 2.0, 2.0, 2.0, 2.0, 2.0])
    lo = -big
    lo[0] = 0.0
    return ParameterSet('payload', P, _pi(model), tuple(f'payload_{n}' for n in _NAMES10),
                        np.zeros(10), lo, big, _project_payload)


def _full(model: pin.Model, ee_joint: int) -> ParameterSet:
    pi = _pi(model)
    nb = model.njoints - 1
    names = tuple(f'{model.names[j]}_{n}' for j in range(1, model.njoints) for n in _NAMES10)
    span = np.maximum(np.abs(pi), 1.0) * 10.0
    return ParameterSet('full', np.eye(10 * nb), np.zeros(10 * nb), names, pi, pi - span,
                        pi + span, project_physical)


def make_parameter_set(model: pin.Model, name: str, ee_joint: int) -> ParameterSet:
    """Build the named set for ``model`` (``ee_joint``: joint index of the end-effector body)."""
    builders = {'link_masses': _link_masses, 'payload': _payload, 'full': _full}
    if name not in builders:
        raise ParameterSetError(
            f"unknown parameter set '{name}', expected one of {PARAMETER_SETS}")
    return builders[name](model, ee_joint)


def _consistent_body(pi: np.ndarray, min_mass: float, min_eig: float) -> np.ndarray:
    """Nearest (in eigenvalues) physically consistent 10-vector of one body."""
    m = max(float(pi[0]), min_mass)
    c = pi[1:4] / m
    I_o = np.array([[pi[4], pi[5], pi[7]], [pi[5], pi[6], pi[8]], [pi[7], pi[8], pi[9]]])
    S = np.array([[0, -c[2], c[1]], [c[2], 0, -c[0]], [-c[1], c[0], 0]])
    I_c = I_o - m * (S.T @ S)
    lam, V = np.linalg.eigh(0.5 * (I_c + I_c.T))
    lam = np.maximum(lam, min_eig)
    lam[2] = min(lam[2], lam[0] + lam[1])  # triangle inequality (eigh sorts ascending)
    inertia = pin.Inertia(m, c, V @ np.diag(lam) @ V.T)
    return inertia.toDynamicParameters()


def project_physical(theta: np.ndarray, min_mass: float = 1e-3,
                     min_eig: float = 1e-6) -> np.ndarray:
    """Project every body of a ``full`` estimate onto physically consistent parameters."""
    out = np.array(theta, dtype=float)
    for b in range(0, out.size, 10):
        out[b:b + 10] = _consistent_body(out[b:b + 10], min_mass, min_eig)
    return out


def _project_payload(theta: np.ndarray) -> np.ndarray:
    """Project a payload: it may vanish (m = 0); otherwise it must be physically consistent."""
    if theta[0] <= 1e-6:
        return np.zeros_like(theta)
    return _consistent_body(theta, 1e-6, 0.0)
