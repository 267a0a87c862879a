"""
A user's path in the runtime and in closed loop, offline (ControllerRuntime.on_path).

The paper's arm through the loop engine (helpers.offline.Loop: the plant starts touching the
surface with no force, so the runtime first approaches it), and the Panda following a small
square on its tilted plane with its masses 30 % off (arm7.py). Contact first, the blend from
the current reference, the end hold, an empty path, the release by a ``ref_*`` change and the
pause in safe mode.
"""
from __future__ import annotations

from helpers.offline import Loop
from helpers.pins import check_pinned, numbers
from hybrid_force_controller.core.law.path import follow_basis, PathLimits, plan_path
from hybrid_force_controller.core.offline.arm7 import (panda_model, panda_scenario,
                                                       square_path_event)
from hybrid_force_controller.core.offline.scenario import run_scenario
from hybrid_force_controller.tools.analysis import compute_metrics, RunLog
from hybrid_force_controller.tools.path_analysis import path_metrics
import numpy as np

DT = 1e-3
JUMP_BOUND_NM = 10.0  # as test_runtime_changes.py


def limits_of(params) -> PathLimits:
    rt = params.runtime
    return PathLimits(rt.path_speed, rt.path_max_accel, rt.path_max_speed, rt.path_max_poses,
                      rt.path_corner_tolerance)


def send(loop: Loop, xs, seq: int = 1, start=None):
    """
    Plan a path along x (the paper's arm moves along x only) from the reference and send it.

    ``start``: the (x_d, xdot_d) to plan from (default: the reference now).
    """
    rt = loop.rt
    points = np.array([[x, 1.6, 0.0] for x in xs])
    x, v = rt.reference(loop.t)[:2] if start is None else start
    plan = plan_path(points, np.zeros(len(points)), x, rt.params.law.n,
                     loop.model.task_axes, limits_of(rt.params), start_v_W=v)
    rt.on_path(plan, seq)
    return plan


def run(loop: Loop, steps: int, feed: bool = True) -> list:
    return [loop.step(feed)[0] for _ in range(steps)]


def series(outs, name: str) -> np.ndarray:
    return np.array([getattr(o, name) for o in outs])


def max_effort_step(outs) -> float:
    return float(np.abs(np.diff(series(outs, 'tau'), axis=0)).max())


def test_contact_first_then_the_path_runs_to_its_end_and_holds_pressing(model):
    loop = Loop(model, ref_amplitude=[0.0, 0.0, 0.0])
    first = run(loop, 1)
    assert first[0].mode == 'approach'  # no force yet: the tool looks for the surface
    plan = send(loop, [1.0, 1.04])
    outs = run(loop, 20)
    assert outs[-1].path.state == 'waiting for contact' and outs[-1].path.fraction == 0.0
    outs += run(loop, round((plan.duration + 1.5) / DT))
    touch = next(i for i, o in enumerate(outs) if o.mode == 'running' and o.in_contact)
    assert all(o.path.fraction == 0.0 for o in outs[:touch])  # waited for contact
    assert {o.path.state for o in outs[touch + 1:touch + 100]} == {'running'}
    assert outs[-1].path.state == 'done' and outs[-1].path.time_left_s == 0.0
    assert outs[-1].path.seq == 1
    hold = outs[-1000:]  # the last second: at the end point, pressing f_d
    np.testing.assert_allclose(series(hold, 'x_d_W')[:, 0], 1.04, atol=1e-12)
    assert np.abs(series(hold, 'x_W')[:, 0] - 1.04).max() < 1e-4
    f_n = series(hold, 'f_W') @ loop.params.law.n
    assert np.abs(f_n - loop.params.law.f_d).max() < 0.01
    assert max_effort_step(outs[touch:]) < JUMP_BOUND_NM


def test_a_path_blends_in_from_the_moving_sine_without_a_jump(model):
    loop = Loop(model)  # the sine: 0.1 m/s at its fastest
    run(loop, 3000)
    before = run(loop, 1)[0]  # the node plans from the last tick's reference
    assert before.xdot_d_W[0] < -0.09  # the sine moves to -x: the path starts behind it
    send(loop, [1.05, 1.0], start=(before.x_d_W, before.xdot_d_W))
    outs = [before] + run(loop, 6000)
    x_d = series(outs, 'x_d_W')[:, 0]
    v_d = np.diff(x_d) / DT
    assert np.abs(v_d).max() < 0.1 + 0.05  # continuous: the sine's speed + path_speed at most
    a_max = loop.params.runtime.path_max_accel
    assert np.abs(np.diff(v_d)).max() / DT < 2.5 * a_max  # the stop, the residual, the path
    assert outs[-1].path.state == 'done' and abs(x_d[-1] - 1.0) < 1e-12
    # it stops where the sine was going, x + v T / 2 (no overshoot beyond), and turns back
    x_stop = before.x_d_W[0] - 0.75 * before.xdot_d_W[0] ** 2 / a_max
    assert x_d.min() > x_stop - 1e-4 and x_d.min() < before.x_d_W[0] - 0.005
    assert max_effort_step(outs) < JUMP_BOUND_NM


def test_an_empty_path_stops_smoothly_and_holds(model):
    loop = Loop(model, ref_amplitude=[0.0, 0.0, 0.0])
    run(loop, 1000)
    send(loop, [1.0, 1.08])
    run(loop, 1500)  # well into the path, at path_speed
    going = run(loop, 1)[0]
    loop.rt.on_path(None)
    outs = [going] + run(loop, 1500)
    x_d = series(outs, 'x_d_W')[:, 0]
    v = np.diff(x_d) / DT
    a_max = loop.params.runtime.path_max_accel
    assert v[0] > 0.04 and np.all(v > -1e-9)  # decelerates, never comes back
    assert np.abs(np.diff(v)).max() / DT <= 1.01 * a_max
    assert np.abs(v[-100:]).max() < 1e-9  # stopped
    assert x_d[-1] - x_d[0] <= 0.75 * 0.05 ** 2 / a_max * 1.01  # x + v T / 2
    assert outs[-1].path.state == 'stopped' and outs[-1].path.seq == 1
    assert max_effort_step(outs) < JUMP_BOUND_NM


def test_a_reference_change_or_a_held_point_releases_the_path(model):
    loop = Loop(model, ref_amplitude=[0.0, 0.0, 0.0])
    run(loop, 1000)
    send(loop, [1.0, 1.05], seq=4)
    run(loop, 500)
    loop.rt.set_params(loop.rt.validate({'ref_center': [0.98, 1.6, 0.0],
                                         'ref_amplitude': [0.0, 0.0, 0.0]}))
    outs = run(loop, 3000)
    assert outs[-1].path.state == 'stopped' and outs[-1].path.seq == 4
    assert abs(outs[-1].x_d_W[0] - 0.98) < 1e-9  # back on the (still) sine
    send(loop, [1.0, 1.05], seq=5)
    run(loop, 500)
    loop.rt.on_reference([0.99, 1.6, 0.0])
    out = run(loop, 1)[0]
    assert out.path.state == 'stopped' and out.path.seq == 5


def test_the_path_stands_still_in_safe_mode_and_goes_on(model):
    loop = Loop(model, ref_amplitude=[0.0, 0.0, 0.0])
    run(loop, 1000)
    send(loop, [1.0, 1.05])
    run(loop, 500)
    before = run(loop, 1)[0].path.fraction
    outs = run(loop, 200, feed=False)  # inputs stop: safe mode after state_timeout
    assert outs[-1].mode == 'safe'
    safe = [o.path for o in outs if o.mode == 'safe']
    assert len({p.fraction for p in safe}) == 1 and safe[0].fraction - before < 0.05
    outs = run(loop, 3000)
    assert outs[-1].mode == 'running' and outs[-1].path.state == 'done'


def test_the_panda_follows_a_small_square_on_its_tilted_plane():
    model = panda_model()
    side, sent = 0.04, {}
    cfg = panda_scenario(model, 6.5, overrides={'ref_amplitude': [0.0, 0.0, 0.0]},
                         events=[square_path_event(1.0, side, sent)])
    result = run_scenario(cfg, model)
    n_W = result.n_W
    window = result.t >= sent['t']
    e_W = (result.x_W - result.x_d_W)[window]
    e_tan = np.linalg.norm(e_W - np.outer(e_W @ n_W, n_W), axis=1)
    assert np.sqrt(np.mean(e_tan ** 2)) <= 1e-3 and e_tan.max() <= 3e-3  # the targets
    f_err = result.f_true_W[window] @ n_W - 5.0
    assert np.sqrt(np.mean(f_err ** 2)) <= 0.1 and result.in_contact[window].all()
    # it traced the square: the actual points span its side in the plane
    B = follow_basis(n_W, model.task_axes)
    span = np.ptp((result.x_W[window] - result.x_W[0]) @ B, axis=0)
    assert np.all(span > side * 0.95) and np.all(span < side * 1.3)
    assert result.runtime._motion.path_progress().state == 'done'
    assert sent['plan'].duration + sent['t'] < 6.5
    log, t_path = RunLog.from_result(result), sent['t']  # the pinned run (test_pinned_figures)
    check_pinned('panda_path', numbers({**compute_metrics(log, t_start=t_path),
                                        **path_metrics(log, t_start=t_path),
                                        'path_start_s': t_path}))


def test_the_logged_position_is_the_references_on_a_path_and_on_a_learnt_normal(model):
    """desired_position (the offline log's x_d, its own short way) equals reference's x_d_W."""
    for overrides, path in (({}, False), ({'ref_amplitude': [0.0, 0.0, 0.0]}, True),
                            ({'n_estimation': True}, False)):
        loop = Loop(model, **overrides)
        run(loop, 1)
        if path:
            send(loop, [1.0, 1.03])
        rt, seen, states = loop.rt, 0, set()
        for _ in range(1500):
            loop.step(True)
            t = loop.t
            x_d = rt.desired_position(t)
            assert np.array_equal(x_d, rt.reference(t).x_d_W), (overrides, t)
            seen += rt._normal.enabled and rt._in.state is not None
            states.add(rt._motion.path_progress().state)
        assert (seen > 0) == ('n_estimation' in overrides)  # the projected branch ran
        assert ('running' in states) == path  # the path's rows, not the sine's
