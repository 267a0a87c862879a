"""Offline study of the online stiffness estimate (issue 13, phase 1); not part of the package.

Open loop: the estimator is fed, after the fact, with the logged signals of the existing
closed loop (:func:`run_scenario`), which does not use it. The force is filtered as the
controller filters it and the contact test is the controller's (``in_contact`` on the
filtered normal force), not the simulator's ground truth.

    .venv/bin/python test/stiffness_study.py            # prints the tables of the report

The closed-loop prototype of phase 2 lives in :mod:`stiffness_prototype`.
"""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hybrid_force_controller.core.control_law import in_contact  # noqa: E402
from hybrid_force_controller.core.filters import LowPassFilter  # noqa: E402
from hybrid_force_controller.core.scenario import (ScenarioConfig, ScenarioResult,  # noqa: E402
                                                   run_scenario)
from hybrid_force_controller.core.stiffness import (StiffnessConfig,  # noqa: E402
                                                    StiffnessEstimator)

STIFFNESSES = (300.0, 500.0, 1700.0, 5000.0)
SCALES = (0.5, 1.5)
CONFIG = StiffnessConfig(enabled=True)


class EstimateTrace(NamedTuple):
    """The estimator's outputs at every sample of a run."""

    t: np.ndarray
    k_hat: np.ndarray
    valid: np.ndarray
    k_s: np.ndarray
    excited: np.ndarray
    excitation_n: np.ndarray  # k_hat |x_n - x_bar| of (S5), N (0 out of contact)
    t_contact: float  # first sample the simulator reports in contact
    estimator: StiffnessEstimator


def estimate_open_loop(res: ScenarioResult, config: StiffnessConfig = CONFIG,
                       f_d: float = 1.0, filter_hz: float = 200.0) -> EstimateTrace:
    """Feed the estimator with a logged run, sample by sample, as the controller would."""
    est = StiffnessEstimator(dataclasses.replace(config, force_filter_hz=filter_hz))
    filt = LowPassFilter(filter_hz)
    n = res.n_W
    dt = float(res.t[1] - res.t[0])
    N = len(res.t)
    k_hat, k_s, exc_n = np.zeros(N), np.zeros(N), np.zeros(N)
    valid, excited = np.zeros(N, bool), np.zeros(N, bool)
    for i in range(N):
        filt.update(res.f_W[i], dt)
        f_n = float(n @ filt.value)
        contact = in_contact(f_n, f_d)
        k_hat[i] = est.update(f_n, float(n @ res.x_W[i]), dt, contact)
        exc_n[i] = est.excitation_n
        valid[i], excited[i], k_s[i] = est.valid, est.excited, est.k_s_command(dt)
    t0 = float(res.t[np.argmax(res.in_contact)])
    return EstimateTrace(res.t, k_hat, valid, k_s, excited, exc_n, t0, est)


def time_within(t: np.ndarray, k_hat: np.ndarray, k: float, tol: float,
                t_contact: float) -> float:
    """Time from ``t_contact`` until k_hat enters ``k (1 +- tol)`` for good (inf: never)."""
    outside = np.flatnonzero(np.abs(k_hat - k) > tol * k)
    if outside.size == 0:
        return max(float(t[0]) - t_contact, 0.0)
    if outside[-1] + 1 >= len(t):
        return float('inf')
    return float(t[outside[-1] + 1]) - t_contact


def open_loop_case(k: float, scale: float, noise: float = 0.0, duration: float = 20.0,
                   delay: int = 2, seed: int = 0) -> dict:
    """One row of the open-loop table."""
    res = run_scenario(ScenarioConfig(k=k, theta_hat0_scale=scale, delay_steps=delay,
                                      noise_sigma=noise, seed=seed, duration=duration))
    tr = estimate_open_loop(res)
    steady = res.t >= 5.0
    used = np.flatnonzero(tr.excited)
    return dict(k=k, scale=scale, noise=noise, trace=tr,
                t_10pct=time_within(tr.t, tr.k_hat, k, 0.10, tr.t_contact),
                t_valid=float(tr.t[np.argmax(tr.valid)]) - tr.t_contact if tr.valid.any()
                else float('inf'),
                final_err=float(tr.k_hat[-1] - k) / k,
                max_err_steady=float(np.max(np.abs(tr.k_hat[steady] - k))) / k,
                last_used=float(tr.t[used[-1]]) if used.size else float('nan'),
                samples_used=tr.estimator.samples_used,
                steady_excitation_n=float(tr.excitation_n[steady].max()),
                steady_force_ripple_n=float(k * np.ptp(res.x_W[steady] @ res.n_W)))


def _print_open_loop() -> None:
    print('Open loop (estimator fed the logs of run_scenario, delay_steps=2)')
    print('  k N/m  masses  noise  t_10%-t_c s  t_valid s  final err  max|err| t>=5  '
          'last used s  samples  max k|x-xbar| t>=5 N  k ptp(x_n) t>=5 N')
    for noise in (0.0, 0.05):
        for k in STIFFNESSES:
            for scale in SCALES:
                r = open_loop_case(k, scale, noise)
                print(f"  {k:5.0f}  {scale:5.1f}  {noise:5.2f}  {r['t_10pct']:11.3f}  "
                      f"{r['t_valid']:9.3f}  {100 * r['final_err']:+8.2f}%  "
                      f"{100 * r['max_err_steady']:11.2f}%  {r['last_used']:11.2f}  "
                      f"{r['samples_used']:7d}  {r['steady_excitation_n']:20.4f}  "
                      f"{r['steady_force_ripple_n']:17.4f}")


if __name__ == '__main__':
    _print_open_loop()
