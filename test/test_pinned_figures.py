"""
Pinned figures of the deterministic offline runs (issue 31, item 1).

The targets the other tests assert allow 300-2000 times the measured errors, so a tracking
regression of ~100x would pass them; here every figure of each run must equal its pin in
test/pinned_figures.json at a relative 1e-6 (test/helpers/pins.py: the tolerance and why).
Each run is an existing scenario, through the functions its own tests use:

* ``paper_theta0.5`` / ``paper_theta1.0``: the ``paper`` executable (tools/paper.py ``main``,
  its figures not drawn) at its defaults, theta_hat(0) half the masses (its default, Fig. 5)
  and exact (ScenarioConfig's default, test_closed_loop_offline); its metrics.json;
* ``stiffness_k*_theta0.5``: the issue-13 runs of test_stiffness_closed_loop (``run``, 12 s,
  2 periods of delay, the masses 50 % low) at k = 300, 500, 1700 and 5000 N/m, its ``metrics``;
* ``panda``: the Panda's 20 s closed loop (arm7.panda_scenario, test_any_arm), compute_metrics
  from 5 s;
* ``panda_path``: the Panda's 4 cm square on its tilted plane (square_path_event at 1 s,
  test_path_runtime), compute_metrics and path_metrics from the path's start;
* ``panda_normal_sphere``: the Panda learning the normal of a sphere under its 10 cm square
  (helpers/offline.py ``panda_run``), compute_metrics from the path's start and
  normal_metrics, with the controller's and the true normals.

The lockstep demo's pin is checked in test_demo.py, on the run its fixture makes.

A pinned figure changes on purpose only: ``HFC_PIN_UPDATE=1`` rewrites the pins (with the
commit, ``git rev-parse --short HEAD``) instead of comparing, and the commit that changes
pinned_figures.json gives the reason in its message.
"""
from __future__ import annotations

import dataclasses
import json

from helpers.offline import panda_run, stiffness_metrics, stiffness_run, STIFFNESSES
from helpers.pins import check_pinned, numbers
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.arm7 import (panda_model, panda_scenario,
                                                       square_path_event)
from hybrid_force_controller.core.offline.scenario import run_scenario
from hybrid_force_controller.tools import paper, plots
from hybrid_force_controller.tools.analysis import compute_metrics, RunLog
from hybrid_force_controller.tools.normal_analysis import normal_metrics
from hybrid_force_controller.tools.path_analysis import path_metrics
import pytest


@pytest.fixture(scope='module')
def paper_arm() -> RobotModel:
    return RobotModel.from_urdf()


@pytest.fixture(scope='module')
def panda() -> RobotModel:
    return panda_model()


@pytest.mark.parametrize('scale', ['0.5', '1.0'])
def test_paper(scale, tmp_path, monkeypatch, capsys):
    """The ``paper`` executable's metrics.json (the figures not drawn: 20 s of plotting)."""
    monkeypatch.setattr(plots, 'write_figures', lambda log, out: [])
    assert paper.main(['--theta-scale', scale, '--out', str(tmp_path)]) == 0
    capsys.readouterr()
    metrics = json.loads((tmp_path / 'metrics.json').read_text())
    check_pinned(f'paper_theta{scale}', numbers(metrics))


@pytest.mark.parametrize('k', STIFFNESSES)
def test_stiffness(paper_arm, k):
    res = stiffness_run(paper_arm, k, 0.5)
    check_pinned(f'stiffness_k{k:.0f}_theta0.5', numbers(stiffness_metrics(res)))


def test_panda(panda):
    res = run_scenario(panda_scenario(panda, 20.0), panda)
    check_pinned('panda', numbers(compute_metrics(RunLog.from_result(res), t_start=5.0)))


def test_panda_path(panda):
    sent: dict = {}
    cfg = panda_scenario(panda, 6.5, overrides={'ref_amplitude': [0.0, 0.0, 0.0]},
                         events=[square_path_event(1.0, 0.04, sent)])
    log = RunLog.from_result(run_scenario(cfg, panda))
    t_path = sent['t']
    figures = {**compute_metrics(log, t_start=t_path), **path_metrics(log, t_start=t_path),
               'path_start_s': t_path}
    check_pinned('panda_path', numbers(figures))


def test_panda_normal_sphere(panda):
    res, t_path = panda_run(panda, 'sphere')
    log = dataclasses.replace(RunLog.from_result(res), n_hat_W=res.n_hat_W,
                              n_true_W=res.n_true_W)
    figures = {**compute_metrics(log, t_start=t_path), **normal_metrics(log),
               'path_start_s': t_path}
    check_pinned('panda_normal_sphere', numbers(figures))
