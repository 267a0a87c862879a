"""Closed loop of controller and plant, offline: the paper's scenario (section V of [1]).

Pure numpy + pinocchio. The controller runs at ``rate_hz`` with zero-order hold; the plant
integrates sub-steps inside each period; ``delay_steps`` delays the sensor-to-actuation
path by whole control periods (a ROS loop between two processes adds 1-2).
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .control_law import HybridForceController
from .environment import ElasticSurface
from .filters import LowPassFilter
from .params import ControllerParams
from .reference import SineReference, blend_start
from .robot_model import RobotModel
from .runtime import params_for_model
from .simulator import ArmSimulator

__all__ = ['ScenarioConfig', 'ScenarioResult', 'make_controller_params', 'run_scenario']

PAPER_Q0 = (0.657, 0.913)


@dataclass(frozen=True)
class ScenarioConfig:
    """The paper's scenario by default: k = 1700 N/m, 20 s, q(0) = (0.657, 0.913).

    The surface passes through the tool's start position (touching, zero force), with
    normal ``n`` (into the surface). ``theta_hat0_scale`` (one factor or one per
    parameter) multiplies the true parameters to give the initial estimate. ``overrides`` are controller parameter values.
    """

    k: float = 1700.0
    duration: float = 20.0
    q0: tuple[float, ...] = PAPER_Q0
    delay_steps: int = 0
    noise_sigma: float = 0.0
    seed: int = 0
    theta_hat0_scale: float | tuple[float, ...] = 1.0
    substeps: int = 2
    overrides: dict[str, Any] = field(default_factory=dict)


@dataclass
class ScenarioResult:
    """Time series of one run (task coordinates padded to 3-D base-frame vectors)."""

    t: np.ndarray
    x_W: np.ndarray
    x_d_W: np.ndarray
    f_W: np.ndarray
    f_true_W: np.ndarray
    f_d_W: np.ndarray
    theta_hat: np.ndarray
    in_contact: np.ndarray
    tau: np.ndarray
    n_W: np.ndarray
    theta_true: np.ndarray
    theta_names: tuple[str, ...]


def make_controller_params(model: RobotModel, overrides: dict[str, Any]) -> ControllerParams:
    """Validated parameters for ``model`` with ``overrides`` applied to the defaults."""
    return params_for_model(model, overrides)


def run_scenario(cfg: ScenarioConfig, model: RobotModel | None = None) -> ScenarioResult:
    """Run the closed loop for ``cfg.duration`` seconds and return its time series."""
    model = RobotModel.from_urdf() if model is None else model
    theta0 = model.theta_nominal * np.asarray(cfg.theta_hat0_scale, dtype=float)
    params = make_controller_params(model, {'theta_hat0': theta0.tolist(), **cfg.overrides})
    ctrl = HybridForceController(model, params)
    p0 = model.kinematics(np.array(cfg.q0), np.zeros(model.n)).p_W
    sim = ArmSimulator(model, ElasticSurface.create(cfg.k, p0, params.n), np.array(cfg.q0),
                       substeps=cfg.substeps, noise_sigma=cfg.noise_sigma, seed=cfg.seed)
    sine = SineReference(params.ref_center, params.ref_amplitude, params.ref_omega)
    dt = 1.0 / params.rate_hz
    steps = int(round(cfg.duration / dt))
    offset, offset_vel = _start_offset(params, sine, p0)
    filt = LowPassFilter(params.force_filter_hz)
    log = _Log(steps, len(theta0))
    meas = sim.measure()
    pending = deque([meas] * (cfg.delay_steps + 1), maxlen=cfg.delay_steps + 1)
    for k in range(steps):
        seen = pending[0]
        filt.update(seen.f_W, dt)
        ref = blend_start(sine(seen.t), offset, seen.t, params.ref_blend_time, offset_vel)
        out = ctrl.step(seen.q, seen.qdot, filt.value, ref, dt)
        log.record(k, meas, ctrl.theta_hat, out.tau)
        meas = sim.step(out.tau, dt)
        pending.append(meas)
    t = np.arange(steps) * dt
    log.x_d[:] = sine.center_W + np.outer(np.sin(sine.omega * t), sine.amplitude_W)
    return log.result(model, params, dt)


def _start_offset(params: ControllerParams, sine: SineReference,
                  p0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Tangential position and velocity offsets of the resting start from x_d(0)."""
    P_t = np.eye(3) - np.outer(params.n, params.n)
    ref0 = sine(0.0)
    return P_t @ (p0 - ref0.x_d_W), P_t @ -ref0.xdot_d_W


class _Log:
    """Preallocated arrays for one run."""

    def __init__(self, steps: int, p: int) -> None:
        z3 = lambda: np.zeros((steps, 3))  # noqa: E731
        self.x, self.x_d, self.f, self.f_true = z3(), z3(), z3(), z3()
        self.theta = np.zeros((steps, p))
        self.contact = np.zeros(steps, dtype=bool)
        self.tau: list[np.ndarray] = []

    def record(self, k: int, meas, theta_hat, tau) -> None:
        self.x[k], self.f[k], self.f_true[k] = meas.p_W, meas.f_W, meas.f_true_W
        self.theta[k], self.contact[k] = theta_hat, meas.in_contact
        self.tau.append(tau)

    def result(self, model: RobotModel, params: ControllerParams, dt: float) -> ScenarioResult:
        steps = len(self.contact)
        return ScenarioResult(np.arange(steps) * dt, self.x, self.x_d, self.f, self.f_true,
                              np.tile(params.f_d * params.n, (steps, 1)), self.theta,
                              self.contact, np.array(self.tau), params.n.copy(),
                              model.theta_nominal.copy(), model.theta_names)
