"""
The stiffness estimate in the tools.

~/stiffness_estimate in bags (optional topic), the RunLog field, the metric
``stiffness_estimate_n_per_m``, fig6_stiffness.png and ``paper --stiffness-estimation``. Real MCAP
bags written with BagWriter (no mocks).
"""
from __future__ import annotations

import json
import math

from helpers.bags import DT_NS, LOG_OFFSET_NS, synthetic_messages, T0_NS, write_bag
from hybrid_force_controller.tools import paper, report
from hybrid_force_controller.tools.analysis import AnalysisError, compute_metrics, RunLog
from hybrid_force_controller.tools.bag_io import (load_run, RECORD_TOPICS, REQUIRED_TOPICS,
                                                  TOPIC_STIFFNESS_ESTIMATE, TYPESTORE)
from hybrid_force_controller.tools.plots import FIGURE_NAMES, STIFFNESS_FIGURE, write_figures
import numpy as np
import pytest


K_HAT_START_S, K_HAT_VALID_S = 1.0, 2.0  # first message; first known (finite) value


def stiffness_messages():
    """~/stiffness_estimate at 100 Hz from t = 1 s: NaN until 2 s, then 500 -> 520 N/m."""
    Float64 = TYPESTORE.types['std_msgs/msg/Float64']
    for i in range(int(K_HAT_START_S * 100), 1001):
        t = i * DT_NS * 1e-9
        value = math.nan if t < K_HAT_VALID_S else 500.0 + 2.0 * (t - K_HAT_VALID_S) / 0.8
        yield TOPIC_STIFFNESS_ESTIMATE, T0_NS + i * DT_NS + LOG_OFFSET_NS, Float64(data=value)


@pytest.fixture(scope='module')
def bag_with_estimate(tmp_path_factory):
    messages = sorted([*synthetic_messages(), *stiffness_messages()], key=lambda m: m[1])
    return write_bag(tmp_path_factory.mktemp('stiffness') / 'run', messages=messages)


def test_the_topic_is_recorded_but_not_required():
    assert (TOPIC_STIFFNESS_ESTIMATE, 'std_msgs/msg/Float64') in RECORD_TOPICS
    assert TOPIC_STIFFNESS_ESTIMATE not in REQUIRED_TOPICS


def test_a_bag_with_the_estimate_loads_it_on_the_position_samples(bag_with_estimate):
    log = load_run(bag_with_estimate)
    assert log.k_hat.shape == log.t.shape and log.k_true is None
    unknown = np.isnan(log.k_hat)
    # NaN before the first message (not held backwards) and while it said NaN
    np.testing.assert_array_equal(unknown, log.t < K_HAT_VALID_S - 1e-9)
    known = ~unknown
    np.testing.assert_allclose(log.k_hat[known], 500.0 + 2.0 * (log.t[known] - 2.0) / 0.8,
                               atol=1e-9)
    m = compute_metrics(log)
    assert m['stiffness_estimate_n_per_m'] == pytest.approx(520.0)


@pytest.mark.parametrize('how', ['drop', 'silence'])
def test_a_bag_without_the_estimate_still_loads_and_reports_null(tmp_path, capsys, how):
    bag = write_bag(tmp_path / 'bag', **{how: (TOPIC_STIFFNESS_ESTIMATE,)})
    assert load_run(bag).k_hat is None
    assert report.main([str(bag), '--out', str(tmp_path / 'out')]) == 0
    metrics = json.loads((tmp_path / 'out' / 'metrics.json').read_text())
    assert 'stiffness_estimate_n_per_m' in metrics
    assert metrics['stiffness_estimate_n_per_m'] is None
    assert not (tmp_path / 'out' / STIFFNESS_FIGURE).exists()
    capsys.readouterr()


def test_report_writes_the_fourth_figure_and_the_metric(bag_with_estimate, tmp_path, capsys):
    out = tmp_path / 'out'
    assert report.main([str(bag_with_estimate), '--out', str(out), '--k-true', '510']) == 0
    metrics = json.loads((out / 'metrics.json').read_text())
    assert metrics['stiffness_estimate_n_per_m'] == pytest.approx(520.0)
    png = out / STIFFNESS_FIGURE
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 5000
    assert str(png) in capsys.readouterr().out


def small_log(**kw) -> RunLog:
    n = 5
    t = np.arange(n) * 0.1
    x = np.tile([1.0, 1.6, 0.0], (n, 1))
    f = np.tile([0.0, -1.0, 0.0], (n, 1))
    return RunLog(t=t, x_W=x, x_d_W=x, f_W=f, f_d_W=f, n_W=np.array([0.0, -1.0, 0.0]),
                  theta_hat=np.ones((n, 2)), theta_names=('m1', 'm2'),
                  in_contact=np.ones(n, bool), **kw)


@pytest.mark.parametrize('k_hat, match', [([1.0, 2.0], 'shape'), ([0.0] * 5, '> 0'),
                                          ([math.inf] * 5, '> 0'), ([-5.0] * 5, '> 0'),
                                          (['a'] * 5, 'numeric')])
def test_run_log_rejects_a_bad_estimate(k_hat, match):
    with pytest.raises(AnalysisError, match=match):
        small_log(k_hat=k_hat)


def test_run_log_estimate_nan_means_unknown_and_the_metric_is_the_last_sample(tmp_path):
    assert math.isnan(compute_metrics(small_log(), t_start=0.0)['stiffness_estimate_n_per_m'])
    ended_unknown = small_log(k_hat=[math.nan, 400.0, 410.0, 420.0, math.nan])
    assert math.isnan(compute_metrics(ended_unknown, t_start=0.0)['stiffness_estimate_n_per_m'])
    log = small_log(k_hat=[math.nan, 400.0, 410.0, 420.0, 430.0], k_true=425)
    assert log.k_true == 425.0 and not log.k_hat.flags.writeable
    assert compute_metrics(log, t_start=0.0)['stiffness_estimate_n_per_m'] == 430.0
    with pytest.raises(AnalysisError, match='k_true'):
        small_log(k_true=0.0)
    paths = write_figures(small_log(k_hat=[math.nan] * 5), tmp_path)  # never known: drawn
    assert [p.name for p in paths] == [*FIGURE_NAMES, STIFFNESS_FIGURE]


def test_paper_with_and_without_the_estimate(tmp_path, capsys):
    """
    metrics.json holds the final k_hat either way (the estimate always runs).

    With it the law's k_s follows it, which at k = 500 shows in the force error.
    """
    metrics = {}
    for flag in ('--stiffness-estimation', '--no-stiffness-estimation'):
        out = tmp_path / flag
        assert paper.main(['--k', '500', '--duration', '6', '--delay-steps', '2',
                           '--theta-scale', '0.5', flag, '--out', str(out)]) == 0
        metrics[flag] = m = json.loads((out / 'metrics.json').read_text())
        assert m['stiffness_estimate_n_per_m'] == pytest.approx(500.0, rel=0.01)
        assert (out / STIFFNESS_FIGURE).stat().st_size > 5000
    on, off = (metrics[f]['rms_force_error_n'] for f in metrics)
    assert on < 0.2 * off, (on, off)  # measured 6e-7 N with, 0.001 N without
    capsys.readouterr()
