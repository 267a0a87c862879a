"""
A user's path, planned and evaluated (core/law/path.py, path_geometry.py, runtime/path_run.py).

Pure numpy, offline: the spline's continuity at corners and ends (numerically), the timing of
timed and untimed paths, the corner tolerance, the tangential projection, every refusal and
the path's own clock (waits, ramps, ends). Runtime and closed loops: test_path_runtime.py.
"""
from __future__ import annotations

import math

from hybrid_force_controller.core.law.path import (follow_basis, MAX_DURATION_S, PathError,
                                                   PathLimits, PathPlan, plan_path, SAMPLE_S)
from hybrid_force_controller.core.runtime.path_run import PathRun
import numpy as np
import pytest

LIMITS = PathLimits(speed=0.05, max_accel=0.5, max_speed=0.25, max_poses=100,
                    corner_tolerance=0.001)
N_W = np.array([0.0, 0.0, -1.0])  # a table, the tool presses down
AXES = (0, 1, 2)
SQUARE = np.array([[0.4, 0.0, 0.2], [0.5, 0.0, 0.2], [0.5, 0.1, 0.2], [0.4, 0.1, 0.2],
                   [0.4, 0.0, 0.2]])
DS = 1e-4  # evaluation step, s


def rows_over(plan, step: float = DS, extra: float = 0.05) -> tuple[np.ndarray, np.ndarray]:
    """Return the times and rows (x_d, xdot_d, xddot_d) from before the start past the end."""
    t = np.arange(-extra, plan.duration + extra, step)
    return t, np.array([plan.rows(s) for s in t])


def assert_continuous_and_consistent(t, R, a_bound: float) -> None:
    """x, v, a change at most by their derivative's bound per step; v, a are x's derivatives."""
    dt = t[1] - t[0]
    v_max = np.linalg.norm(R[:, 1], axis=1).max()
    assert np.linalg.norm(np.diff(R[:, 0], axis=0), axis=1).max() <= 1.01 * v_max * dt
    assert np.linalg.norm(np.diff(R[:, 1], axis=0), axis=1).max() <= 1.01 * a_bound * dt
    jerk = np.linalg.norm(np.diff(R[:, 2], axis=0), axis=1).max() / dt
    assert jerk < 1e3  # finite: no step in the acceleration (a step would be ~ a / DS = 5e3)
    np.testing.assert_allclose(np.gradient(R[:, 0], t, axis=0), R[:, 1], atol=1e-6)
    np.testing.assert_allclose(np.gradient(R[:, 1], t, axis=0), R[:, 2], atol=2e-3)


def untimed(points, start=None, limits=LIMITS, n_W=N_W, axes=AXES):
    points = np.asarray(points, dtype=float)
    return plan_path(points, np.zeros(len(points)), start, n_W, axes, limits)


# ---------------------------------------------------------------- the spline
def test_untimed_square_is_c2_at_rest_at_both_ends_and_within_the_limits():
    plan = untimed(SQUARE)
    t, R = rows_over(plan)
    assert_continuous_and_consistent(t, R, LIMITS.max_accel)
    speed, accel = (np.linalg.norm(R[:, k], axis=1) for k in (1, 2))
    assert speed.max() <= LIMITS.speed * (1 + 1e-9)
    assert accel.max() <= LIMITS.max_accel * (1 + 1e-6)
    assert speed.max() >= 0.99 * LIMITS.speed  # it does reach path_speed on the sides
    for end in (0, -1):  # at rest with zero acceleration, at the first and last pose
        np.testing.assert_allclose(R[end], [SQUARE[end], np.zeros(3), np.zeros(3)], atol=1e-12)
    # the time: 0.4 m at 5 cm/s plus the slow-downs at the rounded corners and the ends
    assert 8.0 < plan.duration < 9.5 and not plan.timed and plan.transit_s == 0.0


def test_corners_are_rounded_within_the_tolerance():
    plan = untimed(SQUARE)
    _, R = rows_over(plan, step=1e-3)
    for corner in SQUARE[1:4]:
        gap = np.linalg.norm(R[:, 0] - corner, axis=1).min()
        assert 0.5 * LIMITS.corner_tolerance < gap <= LIMITS.corner_tolerance + 2e-5


def test_zero_tolerance_stops_at_each_corner_and_passes_it():
    limits = PathLimits(0.05, 0.5, 0.25, 100, 0.0)
    plan = untimed(SQUARE, limits=limits)
    t, R = rows_over(plan)
    assert_continuous_and_consistent(t, R, limits.max_accel)
    for corner in SQUARE[1:4]:
        k = np.argmin(np.linalg.norm(R[:, 0] - corner, axis=1))
        assert np.linalg.norm(R[k, 0] - corner) < 2e-5  # the spline averages 4 samples
        assert np.linalg.norm(R[k, 1]) < 5e-3  # at rest there, within a_max h (full: 5e-2)


def test_a_reversal_stops_and_comes_back():
    plan = untimed([[0.4, 0.0, 0.2], [0.45, 0.0, 0.2], [0.42, 0.0, 0.2]])
    t, R = rows_over(plan)
    assert_continuous_and_consistent(t, R, LIMITS.max_accel)
    assert abs(R[:, 0, 0].max() - 0.45) < 2e-5 and abs(R[-1, 0, 0] - 0.42) < 1e-12


def test_timed_path_honours_its_stamps_one_step_late():
    stamps = np.array([10.0, 12.0, 14.0, 16.0, 18.0])  # absolute stamps: relative to the first
    plan = plan_path(SQUARE, stamps, None, N_W, AXES, LIMITS)
    assert plan.timed and math.isclose(plan.duration, 8.0 + 2 * SAMPLE_S)
    for p, s in zip(SQUARE, stamps - stamps[0]):
        # a corner is cut by sqrt(2) v h / 6 = 0.12 mm (the spline averages four samples)
        assert np.linalg.norm(plan.rows(s + SAMPLE_S)[0] - p) < 1.5e-4
    t, R = rows_over(plan)
    assert np.linalg.norm(R[:, 1], axis=1).max() <= 0.05 * (1 + 1e-9)  # 10 cm in 2 s
    assert np.abs(np.diff(R[:, 0], axis=0)).max() < 0.05 * DS * 1.01  # continuous


def test_only_the_tangential_part_is_followed():
    lifted = SQUARE + np.array([[0, 0, 0.0], [0, 0, 0.01], [0, 0, -0.02], [0, 0, 0.03], [0] * 3])
    start = np.array([0.4, 0.0, 0.25])
    plan = untimed(lifted, start=start)
    _, R = rows_over(plan, step=1e-3)
    np.testing.assert_allclose(R[:, 0, 2], 0.25, atol=1e-12)  # along n: the start's, always
    np.testing.assert_allclose(R[:, 1:, 2], 0.0, atol=1e-12)


def test_follow_basis_is_the_tangent_plane_within_the_task_space():
    planar = follow_basis(np.array([0.0, -1.0, 0.0]), (0, 1))  # the paper's arm: x only
    np.testing.assert_allclose(np.abs(planar), [[1.0], [0.0], [0.0]], atol=1e-12)
    tilted = np.array([0.0, math.sin(0.3), -math.cos(0.3)])
    B = follow_basis(tilted, AXES)
    assert B.shape == (3, 2)
    np.testing.assert_allclose(B.T @ B, np.eye(2), atol=1e-12)
    np.testing.assert_allclose(tilted @ B, 0.0, atol=1e-12)


def test_a_path_away_from_the_start_gets_a_transit_at_rest_at_the_first_pose():
    start = np.array([0.35, -0.03, 0.2])
    plan = untimed(SQUARE, start=start)
    t, R = rows_over(plan)
    assert_continuous_and_consistent(t, R, LIMITS.max_accel)
    np.testing.assert_allclose(R[0, 0], start, atol=1e-12)
    assert plan.transit_s > 1.0  # 5.8 cm at <= 5 cm/s
    at_first = plan.rows(plan.transit_s + SAMPLE_S)
    np.testing.assert_allclose(at_first[0], SQUARE[0], atol=1e-9)
    assert np.linalg.norm(at_first[1]) < 1e-9
    assert np.linalg.norm(R[:, 2], axis=1).max() <= LIMITS.max_accel * (1 + 1e-6)


def test_a_single_pose_is_a_point_to_point_move():
    plan = untimed([[0.45, 0.02, 0.2]], start=np.array([0.4, 0.0, 0.2]))
    t, R = rows_over(plan)
    assert_continuous_and_consistent(t, R, LIMITS.max_accel)
    np.testing.assert_allclose(R[-1, 0], [0.45, 0.02, 0.2], atol=1e-12)


# ---------------------------------------------------------------- refusals
@pytest.mark.parametrize('mutate,words', [
    (lambda p, s: (np.vstack([p] * 30), np.zeros(150)), '150 poses: more than path_max_poses'),
    (lambda p, s: (np.where(np.arange(15).reshape(5, 3) == 7, np.nan, p), s),
     'non-finite position in pose 2'),
    (lambda p, s: (p, np.array([0.0, 1.0, np.inf, 3.0, 4.0])), 'non-finite stamp in pose 2'),
    (lambda p, s: (p, np.array([0.0, 2.0, 1.0, 6.0, 8.0])),
     'non-monotonic stamps: pose 2 at 1 s comes before pose 1 at 2 s'),
    (lambda p, s: (p, np.array([0.0, 0.2, 4.0, 6.0, 8.0])),
     'faster than path_max_speed = 0.25 m/s: 0.5 m/s from pose 0 to pose 1'),
    (lambda p, s: (p, np.array([0.0, 0.0, 4.0, 6.0, 8.0])),
     'faster than path_max_speed = 0.25 m/s: inf m/s from pose 0 to pose 1'),
    (lambda p, s: (p, np.array([0.0, 1e4, 2e4, 3e4, 4e4])), 'longer than 10000 s'),
    (lambda p, s: (p[:0], s[:0]), 'an empty path has no plan'),
], ids=['poses', 'nan', 'inf-stamp', 'non-monotonic', 'fast', 'same-stamp', 'long', 'empty'])
def test_refusals_say_why(mutate, words):
    points, stamps = mutate(SQUARE.copy(), np.zeros(5))
    with pytest.raises(PathError, match=words.replace('(', r'\(').replace('.', r'\.')):
        plan_path(points, stamps, None, N_W, AXES, LIMITS)


def test_an_untimed_path_too_long_is_refused():
    far = np.array([[0.0, 0.0, 0.0], [MAX_DURATION_S * LIMITS.speed * 1.01, 0.0, 0.0]])
    with pytest.raises(PathError, match='longer than 10000 s at path_speed'):
        untimed(far)


def test_slow_motion_along_n_only_is_not_too_fast():
    """Speed is checked on the tangential part: a dive along n between stamps is allowed."""
    points = np.array([[0.4, 0.0, 0.2], [0.4, 0.0, 0.0], [0.41, 0.0, 0.0]])
    plan = plan_path(points, np.array([0.0, 0.01, 1.0]), None, N_W, AXES, LIMITS)
    assert plan.timed


# ---------------------------------------------------------------- the path's clock
def run_clock(run: PathRun, go, seconds: float, dt: float = 1e-3) -> np.ndarray:
    out = []
    for _ in range(round(seconds / dt)):
        run.advance(dt, go)
        out.append(run.rows())
    return np.array(out)


def test_the_clock_waits_out_of_contact_and_starts_at_full_rate_from_rest():
    run = PathRun(untimed(SQUARE), 7, LIMITS.max_accel)
    waiting = run_clock(run, False, 0.5)
    assert run.sigma == 0.0 and run.progress().state == 'waiting for contact'
    assert np.abs(waiting[:, 0] - SQUARE[0]).max() < 1e-12
    run_clock(run, True, 1.0)
    assert math.isclose(run.sigma, 1.0) and run.progress().state == 'running'
    p = run.progress()
    assert p.seq == 7 and math.isclose(p.fraction, 1.0 / run.plan.duration)
    assert math.isclose(p.time_left_s, run.plan.duration - 1.0)


def test_the_clock_stops_and_goes_on_smoothly_mid_path():
    run = PathRun(untimed(SQUARE), 1, LIMITS.max_accel)
    rows = np.concatenate([run_clock(run, True, 1.0), run_clock(run, False, 0.5),
                           run_clock(run, True, 0.5)])
    dt = 1e-3
    v = np.linalg.norm(rows[:, 1], axis=1)
    assert v[1400] < 1e-12  # stopped (after ramp_s = 0.15 s)
    assert np.linalg.norm(np.diff(rows[:, 0], axis=0), axis=1).max() <= 0.05 * dt * 1.01
    assert np.linalg.norm(np.diff(rows[:, 1], axis=0), axis=1).max() <= 1.01 * 0.5 * dt
    assert np.linalg.norm(rows[:, 2], axis=1).max() <= LIMITS.max_accel * 1.01
    # the reference's velocity is the derivative of its position through the ramps
    np.testing.assert_allclose(np.gradient(rows[:, 0], dt, axis=0)[1:-1], rows[1:-1, 1],
                               atol=2e-4)


def test_the_clock_ends_at_the_last_pose_and_holds():
    run = PathRun(untimed(SQUARE[:2]), 2, LIMITS.max_accel)
    rows = run_clock(run, True, run.plan.duration + 1.0)
    np.testing.assert_allclose(rows[-1], [SQUARE[1], np.zeros(3), np.zeros(3)], atol=1e-12)
    p = run.progress()
    assert p.state == 'done' and p.fraction == 1.0 and p.time_left_s == 0.0


def test_pause_stands_still_and_ramps_up_again():
    run = PathRun(untimed(SQUARE), 3, LIMITS.max_accel)
    run_clock(run, True, 1.0)
    sigma = run.sigma
    run.pause()
    assert np.linalg.norm(run.rows()[1]) == 0.0
    run_clock(run, True, 0.01)
    assert run.sigma - sigma < 0.01 * 0.5  # ramping, not at full rate


def test_plan_polyline_keeps_both_ends():
    plan = PathPlan(np.linspace([0, 0, 0], [1, 0, 0], 1001), SAMPLE_S)
    line = plan.polyline(100)
    assert len(line) <= 101
    np.testing.assert_array_equal(line[[0, -1]], [[0, 0, 0], [1, 0, 0]])
