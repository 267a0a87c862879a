"""
Helpers of the offline tests (no ROS): loops, plants and synthetic signals they share.

* :class:`Loop`: the runtime and the offline plant at 1 kHz through the loop engine;
* :func:`move_surface`: an engine event that moves the surface along its normal;
* :func:`synthetic_press`: a press oscillating on a spring, the stiffness estimate's input, and
  :func:`stiffness_estimator`, :func:`feed_estimator`, :func:`k_s_series` to run one on it;
* :func:`mujoco_arm`, :func:`mujoco_press`: the paper's arm or the Panda on MuJoCo, and a
  damped, gravity-compensated press of its tool (:data:`R_TOOL` its radius);
* :func:`panda_run` (:data:`SURFACES`, :data:`N_TOLD`): the Panda's square on a tilted or
  curved part, told a flat one (test_normal_closed_loop, the pins);
* :func:`stiffness_run`, :func:`stiffness_metrics` (:data:`STIFFNESSES`): issue 13's runs
  (test_stiffness_closed_loop, the pins);
* :func:`run_with_states`: a scenario and the joint states the controller received.
"""
from __future__ import annotations

import math

from hybrid_force_controller.core.config.params import build_params
from hybrid_force_controller.core.model.robot_model import default_urdf_path, RobotModel
from hybrid_force_controller.core.offline.arm7 import (panda_model, PANDA_Q0, panda_scenario,
                                                       panda_urdf_path, square_path_event)
from hybrid_force_controller.core.offline.engine import LoopEngine
from hybrid_force_controller.core.offline.environment import ElasticSurface, sensor_wrench_from_f_W
from hybrid_force_controller.core.offline.scenario import (PAPER_Q0, run_scenario, ScenarioConfig,
                                                           ScenarioResult)
from hybrid_force_controller.core.offline.simulator import ArmSimulator
from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime
from hybrid_force_controller.core.runtime.filters import LowPassFilter
from hybrid_force_controller.tools.analysis import compute_metrics, RunLog
import numpy as np


DT = 1e-3
Q0 = np.array(PAPER_Q0)


class Loop:
    """
    Runtime + plant at 1 kHz through the loop engine.

    ``step(feed)`` runs one period (the plant's state reaches the runtime only when ``feed``) and
    returns the runtime's output and the measurement it was computed from.
    """

    def __init__(self, model: RobotModel, plant_masses=None, input_hook=None,
                 **overrides) -> None:
        self.model = model
        self.params = build_params(model, overrides)
        self.rt = ControllerRuntime(model, self.params)
        p0 = model.kinematics(Q0, np.zeros(model.n)).p_W
        plant = model if plant_masses is None else model.with_theta(plant_masses)
        self.sim = ArmSimulator(plant, ElasticSurface.create(1700.0, p0, self.params.law.n),
                                Q0, substeps=2)
        self.feeding = True
        hook = input_hook or (lambda t, msg: msg)
        self.engine = LoopEngine(self.rt, self.sim, 60.0,
                                 input_hook=lambda t, msg: hook(t, msg) if self.feeding else None)

    @property
    def t(self) -> float:
        return self.engine.t

    @property
    def k(self) -> int:
        return self.engine.k

    @property
    def meas(self):
        return self.engine.meas

    def feed(self, names=None, q=None, qdot=None) -> None:
        """Feed the current measurement straight into the runtime (names, q, qdot overridable)."""
        m, t = self.meas, self.t
        names = list(self.model.joint_names) if names is None else names
        self.rt.on_joint_state(names, m.q if q is None else q,
                               m.qdot if qdot is None else qdot, t)
        self.rt.on_wrench('tool0', sensor_wrench_from_f_W(m.R_W_ee, m.f_W), t)

    def step(self, feed: bool = True):
        self.feeding = feed
        meas = self.engine.step()
        return self.engine.outputs[-1], meas


def move_surface(depth: float):
    """Event action: the surface moves ``depth`` metres along n (away from the tool)."""
    def act(_runtime, plant):
        s = plant.surface
        plant.surface = ElasticSurface.create(s.k, s.x0_W + depth * s.n_W, s.n_W)
        plant._tau_c = None  # the cached contact torque belongs to the old surface
    return act


X0 = -1.6107  # surface position along n, m (the paper scenario's start height)


def synthetic_press(k: float, duration: float = 3.0, f_lo: float = 0.2, f_hi: float = 2.0,
                    hz: float = 0.5, noise: float = 0.0, seed: int = 0,
                    filter_hz: float = 200.0) -> tuple[np.ndarray, np.ndarray]:
    """(f_n filtered, x_n): a press oscillating between f_lo and f_hi on f = k (x - x0)."""
    t = np.arange(int(round(duration / DT))) * DT
    f_true = f_lo + (f_hi - f_lo) * 0.5 * (1.0 - np.cos(2 * np.pi * hz * t))
    x_n = X0 + f_true / k
    f_meas = f_true + np.random.default_rng(seed).normal(0.0, noise, t.size)
    filt = LowPassFilter(filter_hz, size=1)
    f_n = np.array([filt.update(np.array([f]), DT) and float(filt.value[0]) for f in f_meas])
    return f_n, x_n


def stiffness_estimator(**kw):
    """Return a stiffness estimator, enabled, with ``kw`` for its configuration."""
    from hybrid_force_controller.core.law.stiffness import StiffnessConfig, StiffnessEstimator
    return StiffnessEstimator(StiffnessConfig(**{'enabled': True, **kw}))


def feed_estimator(est, f_n, x_n, contact=True) -> np.ndarray:
    """Feed samples (``contact``: one flag or one per sample) at DT; return k_hat after each."""
    contact = np.broadcast_to(contact, np.shape(f_n))
    return np.array([est.update(float(f), float(x), DT, bool(c))
                     for f, x, c in zip(f_n, x_n, contact)])


def k_s_series(est, steps: int) -> np.ndarray:
    """Return the estimator's k_s command over ``steps`` periods of DT."""
    return np.array([est.k_s_command(DT) for _ in range(steps)])


R_TOOL = 0.01  # the MuJoCo tool's radius, m


def mujoco_arm(name):
    """(model, urdf, q0, n_W into the surface) of the paper's arm or the Panda on a table."""
    if name == 'paper':
        return (RobotModel.from_urdf(), default_urdf_path(), np.array([0.657, 0.913]),
                np.array([0.0, -1.0, 0.0]))
    return panda_model(), panda_urdf_path(), np.array(PANDA_Q0), np.array([0.0, 0.0, -1.0])


def mujoco_press(model, plant, f_W, steps=3000):
    """Hold the tool pressing with f_W (gravity compensated, damped) until it settles."""
    import pinocchio as pin
    meas = plant.measure()
    axes = list(model.task_axes)
    for _ in range(steps):
        kin = model.kinematics(meas.q, meas.qdot)
        J = np.zeros((3, model.n))
        J[axes] = kin.J_ee
        g = pin.rnea(model.model, model.data, meas.q, np.zeros(model.n), np.zeros(model.n))
        tau = g + J.T @ (f_W - 30.0 * (J @ meas.qdot)) - 2.0 * meas.qdot
        meas = plant.step(tau, 1e-3)
    return meas


TILT = 0.3
N_TOLD = [0.0, 0.0, -1.0]
SURFACES = {
    'tilted about x': {'surface_normal': (0.0, math.sin(TILT), -math.cos(TILT))},
    'tilted about y': {'surface_normal': (math.sin(TILT), 0.0, -math.cos(TILT))},
    'cylinder': {'surface_shape': 'cylinder', 'surface_radius': 0.3,
                 'surface_axis': (0.0, 1.0, 0.0)},
    'sphere': {'surface_shape': 'sphere', 'surface_radius': 0.5},
}


def panda_run(model, surface: str, estimate: bool = True) -> tuple[ScenarioResult, float]:
    """Run the Panda's square on ``surface``, told N_TOLD; return the result, the path's t."""
    sent: dict = {}
    cfg = panda_scenario(model, 12.0, events=[square_path_event(1.0, 0.1, sent)],
                         noise_sigma=0.05, seed=1, **SURFACES[surface],
                         overrides={'n': N_TOLD, 'n_estimation': estimate,
                                    'ref_amplitude': [0.0, 0.0, 0.0]})
    result = run_scenario(cfg, model)
    assert result.runtime._motion.path_progress().state == 'done'
    return result, sent['t']


STIFFNESSES = (300.0, 500.0, 1700.0, 5000.0)


def stiffness_run(model, k, scale, duration=12.0, **kw) -> ScenarioResult:
    """Run the paper's scenario on a surface of stiffness ``k``, theta_hat(0) ``scale`` off."""
    kw.setdefault('delay_steps', 2)
    return run_scenario(ScenarioConfig(k=k, theta_hat0_scale=scale, duration=duration,
                                       **kw), model)


def stiffness_metrics(res: ScenarioResult) -> dict:
    """Return the run's metrics from 5 s."""
    return compute_metrics(RunLog.from_result(res), t_start=5.0)


def run_with_states(cfg: ScenarioConfig, model) -> tuple[ScenarioResult, np.ndarray, np.ndarray]:
    """Run ``cfg``; return the result and the (stamp s, q) of every state the controller got."""
    states: list = []

    def hook(t, msg):
        states.append((t, msg[0].copy()))
        return msg
    result = run_scenario(ScenarioConfig(**{**vars(cfg), 'input_hook': hook}), model)
    return result, np.array([t for t, _ in states]), np.array([q for _, q in states])
