"""Offline speed figures of the ``bench`` executable (never asserted in tests).

Offline figures (always):
- ``controller_step_us_median`` / ``controller_step_us_p99``: one control-law plus
  adaptation step (eqs. 5-11, 26) of the 2-DOF arm along the paper trajectory;
- ``controller_step_7dof_us_median`` / ``_p99``: the same for the 7-DOF Panda (redundant);
- ``sim_realtime_factor`` and ``paper_wall_time_s``: the 20 s paper scenario offline.
``bench --ros`` adds the ROS loop in real time (ros/bench.py).
"""
from __future__ import annotations

import time
import numpy as np

from ..core.control_law import HybridForceController
from ..core.environment import ElasticSurface
from ..core.reference import SineReference, blend_start
from ..core.robot_model import RobotModel
from ..core.scenario import PAPER_Q0, ScenarioConfig, make_controller_params, run_scenario
from ..core.simulator import ArmSimulator


def controller_step_times_us(steps: int = 20000) -> np.ndarray:
    """Wall time of each ``HybridForceController.step`` in the closed paper loop, us."""
    model = RobotModel.from_urdf()
    params = make_controller_params(model, {})
    ctrl = HybridForceController(model, params)
    q0 = np.array(PAPER_Q0)
    surface = ElasticSurface.create(1700.0, model.kinematics(q0, 0 * q0).p_W, params.n)
    sim = ArmSimulator(model, surface, q0, substeps=2)
    sine = SineReference(params.ref_center, params.ref_amplitude, params.ref_omega)
    meas, dt, out = sim.measure(), 1.0 / params.rate_hz, np.empty(steps)
    for k in range(steps):
        ref = blend_start(sine(k * dt), np.zeros(3), k * dt, 0.0)
        t0 = time.perf_counter_ns()
        tau = ctrl.step(meas.q, meas.qdot, meas.f_W, ref, dt).tau
        out[k] = (time.perf_counter_ns() - t0) / 1e3
        meas = sim.step(tau, dt)
    return out


def panda_step_times_us(steps: int = 5000) -> np.ndarray:
    """Wall time of each controller step of the 7-DOF Panda in its closed loop, us."""
    from ..core.arm7 import PANDA_Q0, panda_model, panda_scenario
    model = panda_model()
    cfg = panda_scenario(model)
    params = make_controller_params(model, dict(cfg.overrides))
    ctrl = HybridForceController(model, params)
    q0 = np.array(PANDA_Q0)
    surface = ElasticSurface.create(cfg.k, model.kinematics(q0, 0 * q0).p_W, params.n)
    sim = ArmSimulator(model, surface, q0, substeps=2)
    sine = SineReference(params.ref_center, params.ref_amplitude, params.ref_omega)
    meas, dt, out = sim.measure(), 1.0 / params.rate_hz, np.empty(steps)
    for k in range(steps):
        t0 = time.perf_counter_ns()
        tau = ctrl.step(meas.q, meas.qdot, meas.f_W, sine(k * dt), dt).tau
        out[k] = (time.perf_counter_ns() - t0) / 1e3
        meas = sim.step(tau, dt)
    return out


def offline_figures() -> dict[str, float]:
    """Controller step percentiles and the paper scenario's real-time factor."""
    step_us = controller_step_times_us()
    panda_us = panda_step_times_us()
    t0 = time.perf_counter()
    run_scenario(ScenarioConfig())
    wall = time.perf_counter() - t0
    return {'controller_step_us_median': round(float(np.median(step_us)), 2),
            'controller_step_us_p99': round(float(np.percentile(step_us, 99)), 2),
            'controller_step_7dof_us_median': round(float(np.median(panda_us)), 2),
            'controller_step_7dof_us_p99': round(float(np.percentile(panda_us, 99)), 2),
            'paper_wall_time_s': round(wall, 3),
            'sim_realtime_factor': round(20.0 / wall, 2)}
