"""
The compiled plant's arrays and calls (``plant_impl: compiled``; the kernels: plant_kernels.py).

:func:`compiled_plant` builds a :class:`CompiledPlant` from a :class:`RobotModel`, or says why
it cannot (numba missing, a joint other than a revolute or prismatic one of one DOF, or a step
that does not agree with pinocchio's ABA at a test state); :class:`~.simulator.ArmSimulator` then
runs its Python reference. ``plant_kernels`` is imported here on demand only: the Python plant
never loads numba.
"""
from __future__ import annotations

import importlib
from pathlib import Path
import time
from typing import Any

import numpy as np
import pinocchio as pin

from .environment import ElasticSurface, Surface
from ..model.robot_model import RobotModel

__all__ = ['CompiledPlant', 'compiled_plant', 'plant_kernels_cached', 'surface_array']

_SHAPES = {'plane': 1.0, 'sphere': 2.0, 'cylinder': 3.0}
_AGREEMENT = 1e-9  # relative, at the test state (rounding is 1e-15)
_JF, _SF = 51, 15  # plant_kernels.py's widths of a joint's row of jf, and of sf


def surface_array(surface: Surface | None) -> np.ndarray:
    """Return the kernels' ``sf``: shape code, k, x0, n, radius, centre, axis (zeros if none)."""
    sf = np.zeros(_SF)
    if surface is not None:
        sf[0], sf[1] = _SHAPES[surface.shape], surface.k
        sf[2:5], sf[5:8] = surface.x0_W, surface.n_W
        sf[8] = getattr(surface, 'radius', 0.0)
        sf[9:12] = getattr(surface, 'c_W', np.zeros(3))
        sf[12:15] = getattr(surface, 'axis_W', np.zeros(3))
    return sf


class CompiledPlant:
    """A model's arrays (``ji``, ``jf``, ``cf``: plant_kernels.py) and the two kernels."""

    def __init__(self, model: RobotModel, kernels: Any) -> None:
        self.n = model.n
        self.ji, self.jf, self.cf = _model_arrays(model)
        self._k = kernels

    def step(self, q: np.ndarray, qdot: np.ndarray, tau: np.ndarray, h: float, substeps: int,
             friction: tuple[float, float], sf: np.ndarray) -> tuple[np.ndarray, ...]:
        """Return q, q̇, p_W, R_W_ee and f_W after ``substeps`` steps of ``h`` (new arrays)."""
        n = self.n
        out = (np.empty(n), np.empty(n), np.empty(3), np.empty((3, 3)), np.empty(3))
        self._k.step(self.ji, self.jf, self.cf, sf, q, qdot, tau, h, substeps, friction[0],
                     friction[1], *out)
        return out

    def contact(self, q: np.ndarray, sf: np.ndarray) -> tuple[np.ndarray, ...]:
        """Return f_W, its joint torque ``-J_pᵀ f`` and the tool's p_W, R_W_ee at q."""
        p_W, R_W, f_W, tau_c = np.empty(3), np.empty((3, 3)), np.empty(3), np.empty(self.n)
        self._k.contact(self.ji, self.jf, self.cf, sf, q, p_W, R_W, f_W, tau_c)
        return f_W, tau_c, p_W, R_W


def plant_kernels_cached() -> bool:
    """Say whether the plant's compiled code looks cached beside it (else: a first compile)."""
    return any((Path(__file__).parent / '__pycache__').glob('plant_kernels.*.nbi'))


def compiled_plant(model: RobotModel) -> tuple[CompiledPlant | None, str]:
    """Return the compiled plant of ``model`` and a note, or None and why not."""
    t0 = time.perf_counter()
    try:
        kernels = importlib.import_module(f'{__package__}.plant_kernels')
    except ImportError as exc:
        return None, f'numba is not importable ({exc}): the Python plant runs'
    try:
        plant = CompiledPlant(model, kernels)
    except ValueError as exc:
        return None, f'{exc}: the Python plant runs'
    error = _disagreement(model, plant)
    if error > _AGREEMENT:
        return None, (f"the compiled plant's step differs from pinocchio's ABA by {error:.1e}: "
                      'the Python plant runs')
    done = 'compiled' if any(f.stats.cache_misses for f in (kernels.step, kernels.contact)) \
        else 'loaded'
    return plant, f'plant_impl compiled: numba kernels {done} in {time.perf_counter() - t0:.2f} s'


def _model_arrays(model: RobotModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``ji``, ``jf``, ``cf`` of plant_kernels.py; ValueError for a joint it cannot step."""
    m, n = model.model, model.n
    data = m.createData()
    pin.forwardKinematics(m, data, pin.neutral(m), np.zeros(m.nv))
    ji, jf = np.zeros(2 * n + 1, dtype=np.int64), np.zeros((n, _JF))
    for i in range(1, m.njoints):
        S = np.asarray(data.joints[i].S).reshape(-1) if m.joints[i].nv == 1 else np.zeros(6)
        v, w = S[:3], S[3:]
        if np.allclose(v, 0.0) and abs(np.linalg.norm(w) - 1.0) < 1e-12:
            kind, axis = 0, w
        elif np.allclose(w, 0.0) and abs(np.linalg.norm(v) - 1.0) < 1e-12:
            kind, axis = 1, v
        else:
            raise ValueError(f"joint '{m.names[i]}' ({m.joints[i].shortname()}) is not a "
                             'revolute or prismatic joint of one DOF')
        X = m.jointPlacements[i]
        ji[i - 1], ji[n + i - 1] = m.parents[i] - 1, kind
        jf[i - 1] = np.concatenate((axis, X.rotation.reshape(-1), X.translation,
                                    m.inertias[i].matrix().reshape(-1)))
    frame = m.frames[model.frame_id]
    ji[2 * n] = frame.parentJoint - 1
    R_W_root, p_root = model.root_in_base()
    cf = np.concatenate((m.gravity.linear, frame.placement.rotation.reshape(-1),
                         frame.placement.translation, R_W_root.reshape(-1), p_root))
    return ji, np.ascontiguousarray(jf), cf


def _disagreement(model: RobotModel, plant: CompiledPlant) -> float:
    """Return the kernels' largest relative difference from pinocchio at a fixed test state."""
    rng = np.random.default_rng(7)
    n = model.n
    q, qdot, tau = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n), rng.uniform(-5, 5, n)
    qdd_pin = pin.aba(model.model, model.data, q, qdot, tau)
    h = 1e-3
    q1, qdot1, *_ = plant.step(q, qdot, tau, h, 1, (0.0, 0.0), surface_array(None))
    qdd = (qdot1 - qdot) / h
    J = pin.computeFrameJacobian(model.model, model.data, q, model.frame_id,
                                 pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[:3]
    T = pin.updateFramePlacement(model.model, model.data, model.frame_id)
    p_W, R_W, J_W = model.base_from_root(T.translation, T.rotation, J)
    n_W = np.ones(3) / np.sqrt(3.0)  # a plane 1 cm into the tool: a force along every axis
    sf = surface_array(ElasticSurface.create(1000.0, p_W - 0.01 * n_W, n_W))
    _, tau_c, p_k, R_k = plant.contact(q, sf)
    tau_c_pin = -(J_W.T @ (10.0 * n_W))
    scale = 1.0 + float(np.abs(qdd_pin).max())
    return max(float(np.abs(qdd - qdd_pin).max()) / scale,
               float(np.abs(tau_c - tau_c_pin).max()) / 10.0,
               float(np.abs(p_k - p_W).max()), float(np.abs(R_k - R_W).max()))
