"""
Offline speed figures of the ``bench`` executable (never asserted in tests).

- ``controller_step_us_median`` / ``_p99``: one ``ControllerRuntime.tick`` (inputs already
  stored: filter, reference, control law (5)-(11), adaptation (26), limits) of the 2-DOF
  arm along the paper trajectory, driven by the loop engine;
- ``controller_step_7dof_us_median`` / ``_p99``: the same for the 7-DOF Panda (redundant);
- ``sim_realtime_factor`` and ``paper_wall_time_s``: the 20 s paper scenario offline.
``bench --ros`` adds the ROS loop in real time (ros/bench.py).
"""
from __future__ import annotations

import time

import numpy as np

from ..core.arm7 import panda_model, panda_scenario
from ..core.scenario import run_scenario, ScenarioConfig


def _tick_us(cfg: ScenarioConfig, model=None) -> np.ndarray:
    """Wall time of every runtime tick of one offline run, us."""
    result = run_scenario(cfg, model, clock_ns=time.perf_counter_ns)
    return result.log.tick_ns / 1e3


def offline_figures() -> dict[str, float]:
    """Measure the controller step percentiles and the paper scenario's real-time factor."""
    step_us = _tick_us(ScenarioConfig(duration=20.0))
    panda = panda_model()
    panda_us = _tick_us(panda_scenario(panda, duration=5.0), panda)
    t0 = time.perf_counter()
    run_scenario(ScenarioConfig())
    wall = time.perf_counter() - t0
    return {'controller_step_us_median': round(float(np.median(step_us)), 2),
            'controller_step_us_p99': round(float(np.percentile(step_us, 99)), 2),
            'controller_step_7dof_us_median': round(float(np.median(panda_us)), 2),
            'controller_step_7dof_us_p99': round(float(np.percentile(panda_us, 99)), 2),
            'paper_wall_time_s': round(wall, 3),
            'sim_realtime_factor': round(20.0 / wall, 2)}
