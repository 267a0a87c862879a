"""
``report`` on a bag with the learnt normal and the sim tool's axis: the normal's and tool's errors.

normal_error_deg, its window, fig8_normal.png; the tilt error, the tilt moment, fig9.

Synthetic MCAP bags written with BagWriter (helpers.bags), 10 s at 100 Hz: a plane
tilted 0.3 rad about x (``/sim/contact_normal``), the controller told n = [0, 0, -1]. The tool
rests until 2 s (but for a 0.1 s jolt at 0.5 s, up to 3 cm/s: not sliding), then slides along x
at 5 cm/s; its normal (``~/surface_normal``) turns from
the told n to 1 deg off the truth by 4 s, and a 2.5 deg blip at 3.5 s (inside the settling
window, which must not count). The true force along the true normal is 5 N +- 0.1 N (the force
along the told n would be 4.8 N: the report must use the true normal). The tool's axis
(``/sim/tool_axis``) lies 10 deg off the true normal until 3 s, then AXIS_DEG off it, and the
true moment (``/sim/contact_wrench``'s torque) is 0.02 N m across the normal plus 0.5 N m along
it (the spin: not a tilt moment).
"""
from __future__ import annotations

import json
import math

from helpers.bags import array_msg, header, point_msg, run_report, samples, wrench_msg, write_bag
from hybrid_force_controller.tools.bag_io import (load_run, TOPIC_CONTACT_NORMAL,
                                                  TOPIC_CONTACT_WRENCH, TOPIC_SURFACE_NORMAL,
                                                  TOPIC_THETA_HAT, TOPIC_TOOL_AXIS, TOPIC_WRENCH,
                                                  TOPIC_WRENCH_DESIRED, TOPIC_X, TOPIC_X_DESIRED,
                                                  TYPESTORE)
from hybrid_force_controller.tools.normal_analysis import normal_metrics
import numpy as np
import pytest

TILT = 0.3
N_TRUE = np.array([0.0, math.sin(TILT), -math.cos(TILT)])
N_TOLD = np.array([0.0, 0.0, -1.0])
M_TILT = np.array([0.02, 0.0, 0.0])  # N m, across N_TRUE
T_SLIDE = 2.0
FINAL_ERROR_DEG = 1.0
AXIS_DEG = 0.4


def vector_msg(ns: int, v) -> object:
    vec = TYPESTORE.types['geometry_msgs/msg/Vector3'](
        x=float(v[0]), y=float(v[1]), z=float(v[2]))
    return TYPESTORE.types['geometry_msgs/msg/Vector3Stamped'](header=header(ns), vector=vec)


def n_hat_at(t: float) -> np.ndarray:
    """Return the controller's normal: the told n, turning from T_SLIDE, 1 deg short by 4 s."""
    full = math.radians(math.degrees(TILT) - FINAL_ERROR_DEG)
    angle = full * min(max((t - T_SLIDE) / 2.0, 0.0), 1.0)
    if 3.5 <= t < 3.6:
        angle += math.radians(2.5)
    return np.array([0.0, math.sin(angle), -math.cos(angle)])


def normal_messages():
    """(topic, log_ns, msg) of the run of the module docstring."""
    start = np.array([0.5, 0.0, 0.4])
    along = np.array([1.0, 0.0, 0.0])
    for ns, log_ns, t in samples():
        x = start + 0.05 * max(t - T_SLIDE, 0.0) * along
        if 0.5 <= t < 0.6:  # a jolt at start-up
            x = x + 1e-3 * math.sin(math.pi * (t - 0.5) / 0.1) * along
        n_hat = n_hat_at(t)
        f_true = (5.0 + 0.1 * math.sin(2 * math.pi * t)) * N_TRUE
        yield TOPIC_X, log_ns, point_msg(ns, x + 1e-4 * along)
        yield TOPIC_X_DESIRED, log_ns, point_msg(ns, x)
        yield TOPIC_WRENCH, log_ns, wrench_msg(ns, f_true)
        yield TOPIC_CONTACT_WRENCH, log_ns, wrench_msg(ns, f_true, M_TILT + 0.5 * N_TRUE)
        yield TOPIC_WRENCH_DESIRED, log_ns, wrench_msg(ns, 5.0 * n_hat)
        yield TOPIC_THETA_HAT, log_ns, array_msg([1.3, 0.9], 'm1,m2')
        yield TOPIC_SURFACE_NORMAL, log_ns, vector_msg(ns, n_hat)
        yield TOPIC_CONTACT_NORMAL, log_ns, vector_msg(ns, N_TRUE)
        yield TOPIC_TOOL_AXIS, log_ns, vector_msg(ns, tool_axis_at(t))


def tool_axis_at(t: float) -> np.ndarray:
    """Return the tool's axis: 10 deg off the true normal until 3 s, then AXIS_DEG (about x)."""
    a = TILT + math.radians(10.0 if t < 3.0 else AXIS_DEG)
    return np.array([0.0, math.sin(a), -math.cos(a)])


@pytest.fixture(scope='module')
def normal_bag(tmp_path_factory):
    return write_bag(tmp_path_factory.mktemp('normal_bags') / 'tilted',
                     messages=normal_messages())


def test_the_normal_metrics_from_a_bag(normal_bag):
    log = load_run(normal_bag)
    np.testing.assert_allclose(log.n_true_W, np.tile(N_TRUE, (log.t.size, 1)), atol=1e-12)
    m = normal_metrics(log)
    assert m['sliding_begins_s'] == pytest.approx(T_SLIDE, abs=0.02)
    # from T_SLIDE + 2 s: the final 1 deg, and the 2.5 deg blip at 3.5 s is before the window
    assert m['normal_error_deg'] == pytest.approx(FINAL_ERROR_DEG, abs=1e-6)


def test_report_writes_normal_error_and_the_figure(normal_bag, tmp_path, capsys):
    rc, out, err = run_report(normal_bag, tmp_path / 'out', capsys, '--t-start', '0')
    assert rc == 0, err
    metrics = json.loads((tmp_path / 'out' / 'metrics.json').read_text())
    assert metrics['normal_error_deg'] == pytest.approx(FINAL_ERROR_DEG, abs=1e-6)
    assert metrics['sliding_begins_s'] == pytest.approx(T_SLIDE, abs=0.02)
    # the true force along the true normal: 0.1 N of ripple, not the 0.2 N offset along n
    assert metrics['rms_force_error_n'] == pytest.approx(0.1 / math.sqrt(2), abs=2e-3)
    # the tangential error in n_hat's plane: the 0.1 mm along the motion
    assert metrics['rms_position_error_m'] == pytest.approx(1e-4, rel=1e-6)
    assert (tmp_path / 'out' / 'fig8_normal.png').stat().st_size > 10_000
    assert 'fig8_normal.png' in out


def test_a_bag_without_the_normals_reports_null(tmp_path, capsys):
    bag = write_bag(tmp_path / 'plain', messages=(
        m for m in normal_messages() if m[0] not in (TOPIC_SURFACE_NORMAL, TOPIC_CONTACT_NORMAL)))
    rc, out, err = run_report(bag, tmp_path / 'out', capsys)
    assert rc == 0, err
    metrics = json.loads((tmp_path / 'out' / 'metrics.json').read_text())
    assert metrics['normal_error_deg'] is None and metrics['sliding_begins_s'] is None
    assert not (tmp_path / 'out' / 'fig8_normal.png').exists()


def test_report_writes_the_tool_tilt_the_tilt_moment_and_the_figure(normal_bag, tmp_path, capsys):
    rc, out, err = run_report(normal_bag, tmp_path / 'out', capsys, '--t-start', '0')
    assert rc == 0, err
    metrics = json.loads((tmp_path / 'out' / 'metrics.json').read_text())
    # from T_SLIDE + 2 s (normal_error_deg's window): the final AXIS_DEG, not the 10 deg before
    assert metrics['rms_tool_tilt_error_deg'] == pytest.approx(AXIS_DEG, abs=1e-6)
    assert metrics['max_tool_tilt_error_deg'] == pytest.approx(AXIS_DEG, abs=1e-6)
    assert metrics['rms_moment_n_m'] == pytest.approx(0.02, abs=1e-9)  # the spin's 0.5 left out
    assert 'fig9_orientation.png' in out
    rc, out, err = run_report(normal_bag, tmp_path / 'tilted', capsys, '--t-start', '0',
                              '--tool-tilt', repr(math.radians(AXIS_DEG)))
    metrics = json.loads((tmp_path / 'tilted' / 'metrics.json').read_text())
    assert metrics['rms_tool_tilt_error_deg'] == pytest.approx(0.0, abs=1e-6)  # the set tilt


def test_a_bag_without_the_tool_axis_reports_no_orientation(tmp_path, capsys):
    bag = write_bag(tmp_path / 'point', messages=(
        m for m in normal_messages() if m[0] != TOPIC_TOOL_AXIS))
    rc, out, err = run_report(bag, tmp_path / 'out', capsys)
    assert rc == 0, err
    metrics = json.loads((tmp_path / 'out' / 'metrics.json').read_text())
    assert 'rms_tool_tilt_error_deg' not in metrics and 'fig9_orientation.png' not in out
