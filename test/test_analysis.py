"""Metrics of synthetic run logs with known signals, and input validation."""
from __future__ import annotations

import dataclasses
import math

from hybrid_force_controller.tools.analysis import (align, AnalysisError, compute_metrics,
                                                    METRIC_KEYS, RunLog, surface_axis)
import numpy as np
import pytest


DT = 0.01
N_SURF_W = np.array([0.0, -1.0, 0.0])  # the paper arm pushes along -y


def make_log(duration: float = 10.0, **overrides) -> RunLog:
    """Build a perfect run on the paper's task: x_d = 1 + 0.1 sin t, f_d = 1 N along n."""
    t = np.arange(0.0, duration + DT / 2, DT)
    n = t.size
    x_d_W = np.column_stack([1.0 + 0.1 * np.sin(t), np.zeros(n), np.zeros(n)])
    f_d_W = np.tile(N_SURF_W, (n, 1))
    fields = {'t': t, 'x_W': x_d_W.copy(), 'x_d_W': x_d_W, 'f_W': f_d_W.copy(), 'f_d_W': f_d_W,
              'n_W': N_SURF_W,
              'theta_hat': np.column_stack([np.full(n, 1.3), 0.9 - 0.01 * t]),
              'theta_names': ('m1', 'm2'), 'in_contact': np.ones(n, dtype=bool)}
    fields.update(overrides)
    return RunLog(**fields)


def test_perfect_run_has_zero_errors_and_all_keys():
    metrics = compute_metrics(make_log())
    assert tuple(metrics) == METRIC_KEYS
    for key in ('rms_position_error_m', 'max_position_error_m', 'rms_force_error_n',
                'max_force_error_n', 'contact_lost_s'):
        assert metrics[key] == pytest.approx(0.0, abs=1e-12)
    assert metrics['theta_hat_final'] == pytest.approx([1.3, 0.8])
    assert metrics['sim_time_s'] == pytest.approx(10.0)
    assert math.isnan(metrics['wall_time_s'])
    assert compute_metrics(make_log(), wall_time_s=2.5)['wall_time_s'] == 2.5


def test_constant_tangential_error_of_1mm():
    base = make_log()
    x_W = base.x_d_W + np.array([1e-3, 0.0, 0.0])
    metrics = compute_metrics(dataclasses.replace(base, x_W=x_W))
    assert metrics['rms_position_error_m'] == pytest.approx(1e-3, rel=1e-9)
    assert metrics['max_position_error_m'] == pytest.approx(1e-3, rel=1e-9)


def test_normal_position_error_is_not_a_tangential_error():
    base = make_log()
    x_W = base.x_d_W + np.array([0.0, 5e-3, 0.0])  # penetration depth, along n
    metrics = compute_metrics(dataclasses.replace(base, x_W=x_W))
    assert metrics['max_position_error_m'] == pytest.approx(0.0, abs=1e-15)


def test_sine_force_error_rms_is_amplitude_over_sqrt2():
    base = make_log()
    amplitude = 0.2
    f_W = base.f_d_W + np.outer(amplitude * np.sin(2.0 * np.pi * base.t), N_SURF_W)
    metrics = compute_metrics(dataclasses.replace(base, f_W=f_W))
    assert metrics['rms_force_error_n'] == pytest.approx(amplitude / math.sqrt(2.0), abs=1e-3)
    assert metrics['max_force_error_n'] == pytest.approx(amplitude, abs=1e-3)


def test_true_force_replaces_measured_force():
    base = make_log()
    noisy_W = base.f_d_W + np.outer(np.random.default_rng(0).normal(0, 0.5, base.t.size),
                                    N_SURF_W)
    true_W = base.f_d_W + 0.1 * N_SURF_W
    metrics = compute_metrics(dataclasses.replace(base, f_W=noisy_W, f_true_W=true_W))
    assert metrics['rms_force_error_n'] == pytest.approx(0.1)
    assert metrics['max_force_error_n'] == pytest.approx(0.1)


def test_t_start_excludes_the_transient():
    base = make_log()
    x_W = base.x_d_W.copy()
    x_W[base.t < 4.0, 0] += 0.5  # large error only before t_start = 5 s
    metrics = compute_metrics(dataclasses.replace(base, x_W=x_W))
    assert metrics['max_position_error_m'] == pytest.approx(0.0, abs=1e-15)
    assert compute_metrics(dataclasses.replace(base, x_W=x_W),
                           t_start=0.0)['max_position_error_m'] == pytest.approx(0.5)


def test_contact_loss_of_half_a_second():
    base = make_log()
    in_contact = np.ones(base.t.size, dtype=bool)
    in_contact[:100] = False  # before first contact: not a loss
    in_contact[700:750] = False  # 50 samples x 10 ms
    metrics = compute_metrics(dataclasses.replace(base, in_contact=in_contact))
    assert metrics['contact_lost_s'] == pytest.approx(0.5)
    assert metrics['contact_lost_window_s'] == pytest.approx(0.5)  # t = 7.0-7.5 s


def test_contact_loss_before_the_window_is_not_in_the_window():
    base = make_log()
    in_contact = np.ones(base.t.size, dtype=bool)
    in_contact[200:230] = False  # 0.3 s lost at t = 2 s (a start-up transient)
    metrics = compute_metrics(dataclasses.replace(base, in_contact=in_contact), t_start=5.0)
    assert metrics['contact_lost_s'] == pytest.approx(0.3)
    assert metrics['contact_lost_window_s'] == 0.0


def test_never_in_contact_counts_the_whole_run():
    log = make_log(in_contact=np.zeros(1001, dtype=bool))
    assert compute_metrics(log)['contact_lost_s'] == pytest.approx(10.0)
    assert compute_metrics(log, t_start=5.0)['contact_lost_window_s'] == pytest.approx(5.0)


def test_no_samples_after_t_start():
    with pytest.raises(AnalysisError, match='no samples at or after t_start'):
        compute_metrics(make_log(duration=2.0))


@pytest.mark.parametrize('field, value, message', [
    ('x_W', np.zeros((1001, 2)), 'x_W: expected shape'),
    ('f_d_W', np.zeros((10, 3)), 'f_d_W: expected shape'),
    ('t', np.zeros((1001, 1)), 't: expected shape'),
    ('t', np.arange(1001)[::-1] * 0.01, 'non-decreasing'),
    ('n_W', np.array([0.0, -2.0, 0.0]), 'unit vector'),
    ('theta_hat', np.zeros(1001), 'theta_hat: expected shape'),
    ('theta_names', ('m1',), 'theta_names'),
    ('in_contact', np.ones(5, dtype=bool), 'in_contact'),
    ('theta_true', np.ones(3), 'theta_true'),
    ('f_true_W', np.ones((1001, 2)), 'f_true_W'),
    ('f_W', np.full((1001, 3), np.nan), 'NaN or inf'),
])
def test_bad_fields_raise_analysis_error(field, value, message):
    with pytest.raises(AnalysisError, match=message):
        make_log(**{field: value})


def test_empty_log_and_wrong_type_raise():
    with pytest.raises(AnalysisError, match='no samples'):
        RunLog(t=np.zeros(0), x_W=np.zeros((0, 3)), x_d_W=np.zeros((0, 3)),
               f_W=np.zeros((0, 3)), f_d_W=np.zeros((0, 3)), n_W=N_SURF_W,
               theta_hat=np.zeros((0, 1)), theta_names=('a',), in_contact=np.zeros(0, bool))
    with pytest.raises(AnalysisError, match='expected a RunLog'):
        compute_metrics({'t': [0.0]})
    assert issubclass(AnalysisError, ValueError)


def test_run_log_arrays_are_private_read_only_copies():
    x_W = np.zeros((1001, 3))
    log = make_log(x_W=x_W)
    x_W[:] = 1.0
    assert np.all(log.x_W == 0.0)
    with pytest.raises(ValueError):
        log.x_W[0, 0] = 1.0


def test_align_is_a_zero_order_hold():
    t_src = np.array([0.0, 1.0, 2.0])
    y_src = np.array([[10.0], [11.0], [12.0]])
    got = align(np.array([-0.5, 0.0, 0.5, 1.0, 1.99, 5.0]), t_src, y_src)
    assert got[:, 0].tolist() == [10.0, 10.0, 10.0, 11.0, 11.0, 12.0]
    with pytest.raises(AnalysisError, match='non-decreasing'):
        align(np.zeros(2), t_src[::-1], y_src)
    with pytest.raises(AnalysisError, match='source stamps'):
        align(np.zeros(2), np.zeros(0), np.zeros((0, 1)))


def test_surface_axis():
    assert surface_axis(N_SURF_W) == 0
    assert surface_axis(np.array([1.0, 0.0, 0.0])) == 1
    assert surface_axis(np.array([0.0, 0.0, -1.0])) == 0
