"""
The learnt surface normal in closed loop, offline (issue 24): the runtime on the paper physics.

The Panda (masses 30 % off, f_d 5 N, a 10 cm untimed square at 5 cm/s from 1 s) is told
n = [0, 0, -1] on a plane tilted 0.3 rad about x and about y, a cylinder R = 0.3 m across its
axis and a sphere R = 0.5 m with the square over its top; mu = 0 (the paper physics has no
friction; the estimator's friction removal is test_normal_estimate.py's), sensor noise 0.05 N.
Sliding begins with the path; the issue's targets hold from 2 s after it (the normal error),
over the whole path (the force along the true normal, the path error in the path's own plane)
and the whole run (contact). The stiffness estimate stays near the truth (3000 N/m) while n_hat
moves. Negative control: the same tilted plane with the estimate off. The paper's arm on its
line tilted 0.3 rad that it is not told: the true force RMS within 0.05 N, contact never lost,
also when theta_hat starts at the demo's 50 %-off masses (the reference's time then waits for
the first touch, controller_runtime.FIRST_TOUCH_S; without that wait the tool ran 3 s off it).
Measured figures are in docs/results.md ("Learning the surface's normal").
"""
from __future__ import annotations

import dataclasses
import math

from helpers.figures import current_test, report_figure
from helpers.offline import N_TOLD, panda_run, SURFACES, TILT
from helpers.pins import check_pinned, numbers
from hybrid_force_controller.core.config.params import build_params
from hybrid_force_controller.core.offline.arm7 import panda_model, panda_scenario
from hybrid_force_controller.core.offline.engine import run_loop
from hybrid_force_controller.core.offline.environment import make_surface
from hybrid_force_controller.core.offline.scenario import (run_scenario, ScenarioConfig,
                                                           ScenarioResult)
from hybrid_force_controller.core.offline.simulator import ArmSimulator
from hybrid_force_controller.core.runtime.controller_runtime import (ControllerRuntime,
                                                                     FIRST_TOUCH_S)
from hybrid_force_controller.core.runtime.surface import MAX_TILT_RAD
from hybrid_force_controller.tools.analysis import compute_metrics, RunLog
from hybrid_force_controller.tools.normal_analysis import normal_metrics
import numpy as np
import pytest

# the issue's targets: normal error (deg), force RMS along the true normal (N), path RMS (m)
TARGETS = {'tilted about x': (2.0, 0.1), 'tilted about y': (2.0, 0.1),
           'cylinder': (3.0, 0.2), 'sphere': (3.0, 0.2)}
PATH_RMS_M = 1e-3
K_TRUE = 3000.0


@pytest.fixture(scope='module')
def panda():
    return panda_model()


def normal_error_deg(result: ScenarioResult) -> np.ndarray:
    """Return the angle between the controller's normal and the true one, per sample, deg."""
    cos = np.sum(result.n_hat_W * result.n_true_W, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def true_force_error(result: ScenarioResult, f_d: float) -> np.ndarray:
    return np.sum(result.f_true_W * result.n_true_W, axis=1) - f_d


def path_error(result: ScenarioResult) -> np.ndarray:
    """Return the tool's distance from the desired point in the path's plane (N_TOLD)."""
    n = np.array(N_TOLD)
    e = result.x_W - result.x_d_W
    return np.linalg.norm(e - np.outer(e @ n, n), axis=1)


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(x ** 2)))


@pytest.fixture(scope='module')
def runs(panda) -> dict:
    return {s: panda_run(panda, s) for s in SURFACES}


@pytest.mark.parametrize('surface', list(SURFACES))
def test_the_panda_learns_the_surface_and_meets_the_issues_targets(runs, surface):
    result, t_slide = runs[surface]
    max_error_deg, force_rms = TARGETS[surface]
    path = result.t >= t_slide
    settled = result.t >= t_slide + 2.0
    figures = {'normal error deg': normal_error_deg(result)[settled].max(),
               'force RMS': rms(true_force_error(result, 5.0)[path]),
               'path RMS': rms(path_error(result)[path]),
               'time out of contact': float((~result.in_contact[result.t >= 0.1]).sum()) * 1e-3}
    report_figure(current_test(), **figures)
    assert figures['normal error deg'] <= max_error_deg, figures
    assert figures['force RMS'] <= force_rms, figures
    assert figures['path RMS'] <= PATH_RMS_M, figures
    assert figures['time out of contact'] == 0.0, figures
    # the reference lies on n_hat's tangent plane through the tool
    n_hat = result.n_hat_W[path]
    assert np.abs(np.sum((result.x_d_W - result.x_W)[path] * n_hat, axis=1)).max() < 2e-4


@pytest.mark.parametrize('surface', list(SURFACES))
def test_the_stiffness_estimate_stays_consistent_while_the_normal_moves(runs, surface):
    """k_hat is learnt with the tool still and held while it slides (surface.py, (M3))."""
    result, t_slide = runs[surface]
    k = result.k_hat[result.t >= t_slide]
    assert np.all(np.isfinite(k))
    assert 0.85 * K_TRUE <= k.min() and k.max() <= 1.15 * K_TRUE, (k.min(), k.max())


def test_the_sphere_run_gives_its_pinned_figures(runs):
    """The sphere's run is a pinned one (test_pinned_figures.py's docstring)."""
    res, t_path = runs['sphere']
    log = dataclasses.replace(RunLog.from_result(res), n_hat_W=res.n_hat_W,
                              n_true_W=res.n_true_W)
    check_pinned('panda_normal_sphere', numbers({**compute_metrics(log, t_start=t_path),
                                                 **normal_metrics(log),
                                                 'path_start_s': t_path}))


def test_negative_control_without_the_estimate_the_tilt_costs_force_and_stiffness(panda, runs):
    result, t_slide = panda_run(panda, 'tilted about x', estimate=False)
    learnt, _ = runs['tilted about x']
    path = result.t >= t_slide
    assert normal_error_deg(result)[path].min() > 17.0  # it keeps the told normal
    off, on = (rms(true_force_error(r, 5.0)[path]) for r in (result, learnt))
    assert off > 3.0 * on and off > 0.15, (off, on)
    assert result.k_hat[-1] < 0.5 * K_TRUE  # x_n = n^T p drifts as the tool slides


def paper_run(tilt: float, estimate: bool, theta_scale=1.0) -> ScenarioResult:
    """Run the paper's scenario (noise 0.05 N) on its line turned ``tilt`` about z, untold."""
    return run_scenario(ScenarioConfig(
        noise_sigma=0.05, seed=2, surface_normal=(math.sin(tilt), -math.cos(tilt), 0.0),
        theta_hat0_scale=theta_scale, overrides={'n_estimation': estimate, 'n_rate_limit': 2.0}))


def test_the_papers_arm_on_a_line_it_is_not_told_about():
    """
    The issue's 17 deg case, turned so that the line stays within the arm's reach.

    Turned +0.3 rad the line leaves the 2 m reach at x = 1.06 m, short of the sine's 1.1 m
    (43.8 N RMS without the estimate, as the issue measured, and not better with it). The
    paper's start blends 0.21 m at up to 0.29 m/s: n_rate_limit 2 rad/s keeps contact while
    n_hat turns 17 deg (the default 0.5 rad/s loses it for 2 s before 5 s).
    """
    result = paper_run(-TILT, True)
    window = result.t >= 5.0
    error = true_force_error(result, 1.0)
    report_figure(current_test(), force_rms_n=rms(error[window]),
                  normal_error_deg=float(normal_error_deg(result)[window].max()))
    assert rms(error[window]) <= 0.05, rms(error[window])
    assert result.in_contact[result.t >= 0.1].all()
    assert normal_error_deg(result)[window].max() <= 3.0


def test_the_papers_line_from_a_wrong_theta_hat_waits_for_the_first_touch():
    """
    The demo's case: the sim's masses [0.65, 1.35] against the URDF's [1.3, 0.9].

    theta_hat from (2, 0.667) times the truth lifts the tool off at once; the reference's time
    stays at 0 until it has touched FIRST_TOUCH_S, so the sine starts on the surface and n_hat
    learns while sliding: no contact lost after the first touch, 0.05 N RMS from 5 s.
    """
    result = paper_run(-TILT, True, theta_scale=(2.0, 0.9 / 1.35))
    touched = np.flatnonzero(result.in_contact)[0]
    assert result.t[touched] <= 0.5
    assert result.in_contact[touched:].all()
    started = result.t[-1] - result.runtime.run_time  # when the reference's time began
    # (the runtime sees the touch in the filtered sensor force: within 50 ms of the true one)
    assert started >= result.t[touched] + FIRST_TOUCH_S - 0.05, started
    window = result.t >= 5.0
    assert rms(true_force_error(result, 1.0)[window]) <= 0.05


def test_with_estimation_off_the_runtime_keeps_the_told_normal(panda):
    params = build_params(panda, {'n': N_TOLD})
    rt = ControllerRuntime(panda, params)
    assert rt.ctrl._moving is None and rt.normal_status().enabled is False
    p0 = panda.kinematics(np.array(panda_scenario(panda).q0), np.zeros(panda.n)).p_W
    plant = ArmSimulator(panda, make_surface('plane', 3000.0, p0, N_TOLD),
                         np.array(panda_scenario(panda).q0), substeps=2)
    run_loop(rt, plant, 0.2)
    out = rt.tick(rt.state_stamp)
    assert out.n_W is params.law.n


def test_switching_the_estimate_on_and_off_and_a_new_n(panda):
    rt = ControllerRuntime(panda, build_params(panda, {'n': N_TOLD, 'n_estimation': True}))
    assert rt.ctrl._moving is not None
    np.testing.assert_array_equal(rt.normal_status().n_hat, N_TOLD)
    rt.set_params(rt.validate({'n': N_TOLD, 'n_estimation': False}))
    assert rt.ctrl._moving is None and rt._normal.n_W is rt.params.law.n
    n_new = [0.0, math.sin(0.1), -math.cos(0.1)]
    rt.set_params(rt.validate({'n': n_new, 'n_estimation': True}))
    np.testing.assert_allclose(rt.normal_status().n_hat, n_new)


def test_a_normal_far_from_the_told_one_is_held_on_the_60_degree_cone(panda):
    """A force 80 deg from n: the estimate follows it, the normal in use stops at 60 deg."""
    rt = ControllerRuntime(panda, build_params(panda, {'n': N_TOLD, 'n_estimation': True,
                                                       'n_rate_limit': 4.0}))
    nrm = rt._normal
    far = np.array([math.sin(1.4), 0.0, -math.cos(1.4)])
    kin = type('Kin', (), {'xdot': np.array([0.0, 0.05, 0.0])})()
    for _ in range(2000):  # 2 s of sliding at 4 rad/s: more than 80 deg
        nrm.update(5.0 * far, kin, 1e-3, True, rt._motion)
    status = rt.normal_status()
    assert status.limited
    assert status.angle_from_n_deg == pytest.approx(math.degrees(MAX_TILT_RAD), abs=1e-6)
    assert math.degrees(math.acos(float(np.array(nrm.estimator.n_hat) @ far))) < 1.0
