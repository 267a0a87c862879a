"""
Pinned figures of the deterministic offline runs (issue 31, item 1).

The targets the other tests assert allow 300-2000 times the measured errors, so a tracking
regression of ~100x would pass them; here every figure of each run must equal its pin in
test/pinned_figures.json at a relative 1e-6 (test/helpers/pins.py: the tolerance and why).
Each run is an existing scenario; the ``paper`` runs are checked here, the others by the test
that already makes the run (one run, two checks: the suite's CPU is what sets its time):

* ``paper_theta0.5`` / ``paper_theta1.0``: the ``paper`` executable (tools/paper.py ``main``,
  its figures not drawn) at its defaults, theta_hat(0) half the masses (its default, Fig. 5)
  and exact (ScenarioConfig's default, test_closed_loop_offline); its metrics.json;
* ``stiffness_k*_theta0.5``: the issue-13 runs (``stiffness_run``, 12 s, 2 periods of delay,
  the masses 50 % low) at k = 300, 500, 1700 and 5000 N/m, its ``metrics``: checked in
  test_stiffness_closed_loop's ``test_the_estimate_converges_and_the_loop_meets_the_targets``;
* ``panda``: the Panda's 20 s closed loop (arm7.panda_scenario), compute_metrics from 5 s:
  test_any_arm's ``test_panda_closed_loop_with_mass_errors``;
* ``panda_path``: the Panda's 4 cm square on its tilted plane (square_path_event at 1 s),
  compute_metrics and path_metrics from the path's start: test_path_runtime's
  ``test_the_panda_follows_a_small_square_on_its_tilted_plane``;
* ``panda_normal_sphere``: the Panda learning the normal of a sphere under its 10 cm square
  (helpers/offline.py ``panda_run``), compute_metrics from the path's start and
  normal_metrics, with the controller's and the true normals: test_normal_closed_loop's
  ``test_the_sphere_run_gives_its_pinned_figures``.

The lockstep demo's pin is checked in test_demo.py, on the run its fixture makes.

A pinned figure changes on purpose only: ``HFC_PIN_UPDATE=1`` rewrites the pins (with the
commit, ``git rev-parse --short HEAD``) instead of comparing, and the commit that changes
pinned_figures.json gives the reason in its message.
"""
from __future__ import annotations

import json

from helpers.pins import check_pinned, numbers
from hybrid_force_controller.tools import paper, plots
import pytest


@pytest.mark.parametrize('scale', ['0.5', '1.0'])
def test_paper(scale, tmp_path, monkeypatch, capsys):
    """The ``paper`` executable's metrics.json (the figures not drawn: 20 s of plotting)."""
    monkeypatch.setattr(plots, 'write_figures', lambda log, out: [])
    assert paper.main(['--theta-scale', scale, '--out', str(tmp_path)]) == 0
    capsys.readouterr()
    metrics = json.loads((tmp_path / 'metrics.json').read_text())
    check_pinned(f'paper_theta{scale}', numbers(metrics))
