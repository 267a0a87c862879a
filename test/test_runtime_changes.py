"""
Live changes in the runtime.

Parameter sets, held references, clock restarts and safe mode keep the effort continuous (no jumps,
no stale state).
"""
from __future__ import annotations

from helpers.offline import Loop
from hybrid_force_controller.core.law.reference import BlendedReference, SineReference
import numpy as np


JUMP_BOUND_NM = 10.0  # 10 % of the 100 N m effort limit


def run(loop: Loop, steps: int) -> list:
    return [loop.step()[0] for _ in range(steps)]


def max_step(outs) -> float:
    taus = np.array([o.tau for o in outs])
    return float(np.abs(np.diff(taus, axis=0)).max())


def test_f_d_set_keeps_filtered_force_and_contact(model):
    loop = Loop(model)
    run(loop, 3000)
    before = loop.rt.tick(loop.t)  # no new wrench since the last tick
    loop.rt.set_params(loop.rt.validate({'f_d': 1.5}))
    after = loop.rt.tick(loop.t + 1e-3)
    assert np.allclose(after.f_W, before.f_W) and after.in_contact


def test_filter_cutoff_change_keeps_value(model):
    loop = Loop(model)
    run(loop, 2000)
    f_before = loop.rt.tick(loop.t).f_W
    loop.rt.set_params(loop.rt.validate({'force_filter_hz': 50.0}))
    assert np.allclose(loop.rt.tick(loop.t + 1e-3).f_W, f_before)


def test_tick_output_force_is_a_copy(model):
    loop = Loop(model)
    out = run(loop, 10)[-1]
    kept = out.f_W.copy()
    run(loop, 10)
    assert np.array_equal(out.f_W, kept)


def test_reference_change_blends_without_effort_jump(model):
    loop = Loop(model)
    run(loop, 6000)
    loop.rt.set_params(loop.rt.validate({'ref_center': [0.95, 1.6, 0.0]}))  # within reach
    outs = run(loop, 3000)
    assert max_step(outs) < JUMP_BOUND_NM
    # and it does get there: x_d ends on the new sine
    t = (loop.k - 1) * 1e-3
    assert abs(outs[-1].x_d_W[0] - (0.95 + 0.1 * np.sin(t - loop.rt._clock.t0))) < 1e-6


def test_held_point_survives_an_unrelated_set_and_is_reached(model):
    loop = Loop(model)
    run(loop, 6000)
    loop.rt.on_reference([0.95, 1.6, 0.0])
    outs = run(loop, 500)
    loop.rt.set_params(loop.rt.validate({'f_d': 1.2}))
    outs += run(loop, 2500)
    assert max_step(outs) < JUMP_BOUND_NM
    assert abs(outs[-1].x_d_W[0] - 0.95) < 1e-9
    assert abs(outs[-1].x_W[0] - 0.95) < 1e-4


def test_clock_restart_resets_integral_and_rate_limiter(model):
    loop = Loop(model, max_effort_rate=0.5)
    run(loop, 3000)
    assert loop.rt.ctrl.h != 0.0 and loop.rt._command.limiter._last is not None
    loop.rt.tick(0.0)  # the clock jumped back
    assert loop.rt.counters['clock_restarts'] == 1
    assert loop.rt.ctrl.h == 0.0 and loop.rt._command.limiter._last is None


def test_safe_mode_respects_the_rate_limit(model):
    rate = 0.5
    loop = Loop(model, max_effort_rate=rate)
    outs = run(loop, 3000)
    outs += [loop.step(feed=False)[0] for _ in range(150)]  # inputs stop: safe mode
    assert outs[-1].mode == 'safe'
    outs += run(loop, 500)  # and come back
    assert outs[-1].mode == 'running'
    assert max_step(outs) <= rate + 1e-9


def test_blended_reference_switch_is_continuous():
    sine = SineReference(np.array([1.0, 1.6, 0.0]), np.array([0.1, 0.0, 0.0]), 1.0)
    ref = BlendedReference(sine, np.array([0.0, -1.0, 0.0]), 2.0)
    before = ref(3.0)
    ref.switch(3.0, x_hold_W=np.array([0.9, 1.6, 0.0]))
    after = ref(3.0)
    assert np.allclose(before.x_d_W[0], after.x_d_W[0])
    assert np.allclose(before.xdot_d_W[0], after.xdot_d_W[0])
    assert np.allclose(ref(5.0).x_d_W, [0.9, 1.6, 0.0]) and np.allclose(ref(5.0).xdot_d_W, 0)
