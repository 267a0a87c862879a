"""
``report`` on a bag with a user's path: the path metrics, their window and fig7_path.png.

Synthetic MCAP bags written with BagWriter (helpers.bags): a 5 cm square traced in
the surface plane (n = -y) while ``~/path_status`` says ``running``, with a known tangential
error then (0.5 mm) and another before and after (5 mm), plus 3 mm along n that must never
count.
"""
from __future__ import annotations

import json

from helpers.bags import path_messages, run_report, RUNNING_S, write_bag
from hybrid_force_controller.tools.bag_io import load_run
from hybrid_force_controller.tools.path_analysis import path_metrics, surface_basis
import numpy as np
import pytest


@pytest.fixture(scope='module')
def path_bag(tmp_path_factory):
    return write_bag(tmp_path_factory.mktemp('path_bags') / 'square',
                     messages=list(path_messages()))


def test_path_metrics_while_the_path_runs(path_bag, tmp_path, capsys):
    rc, out, err = run_report(path_bag, tmp_path / 'out', capsys)
    assert rc == 0, err
    metrics = json.loads((tmp_path / 'out' / 'metrics.json').read_text())
    assert metrics['path_window'] == 'path running'
    assert metrics['rms_path_error_m'] == pytest.approx(5e-4, rel=1e-6)  # not 5 mm, not n's
    assert metrics['max_path_error_m'] == pytest.approx(5e-4, rel=1e-6)
    png = tmp_path / 'out' / 'fig7_path.png'
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 5000
    assert str(png) in out


def test_the_running_window_follows_the_status(path_bag):
    log = load_run(path_bag)
    assert log.path_running is not None
    running = log.t[log.path_running]
    assert running[0] == pytest.approx(RUNNING_S[0]) and running[-1] == pytest.approx(7.99)
    assert log.path_running.sum() == 600


def test_without_a_path_the_metrics_use_the_position_window(tmp_path, capsys):
    bag = write_bag(tmp_path / 'nopath', messages=list(path_messages(with_status=False)))
    log = load_run(bag)
    assert log.path_running is None
    metrics = path_metrics(log, t_start=8.5)  # after the path: the 5 mm error only
    assert metrics['path_window'] == 't >= 8.5 s'
    assert metrics['rms_path_error_m'] == pytest.approx(5e-3, rel=1e-6)
    rc, _, err = run_report(bag, tmp_path / 'out', capsys)  # and the figure still draws
    assert rc == 0, err
    assert (tmp_path / 'out' / 'fig7_path.png').stat().st_size > 5000


@pytest.mark.parametrize('n_W, rows', [
    ((0.0, 0.0, -1.0), [[1, 0, 0], [0, 1, 0]]),  # a table seen from above: x, y
    ((0.0, -1.0, 0.0), [[1, 0, 0], [0, 0, -1]]),  # the paper's surface
])
def test_surface_basis_spans_the_plane(n_W, rows):
    B = surface_basis(np.array(n_W))
    np.testing.assert_allclose(B, rows, atol=1e-12)
    tilted = np.array([0.0, np.sin(0.3), -np.cos(0.3)])
    B = surface_basis(tilted)
    np.testing.assert_allclose(B @ B.T, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(B @ tilted, 0.0, atol=1e-12)
