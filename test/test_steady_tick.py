"""
The steady tick (core/runtime/steady_tick.py, tick_kernels.py) against the reference tick.

One recorded stream of joint states and wrenches (a closed loop of the paper's arm or the Panda)
is replayed into two runtimes, ``tick_impl`` python (the reference: every tick is
controller_runtime.py's) and compiled (its steady ticks in two kernels), input for input: every
field of every tick's output must agree to a relative 1e-12, and at the end the counters, the
mode, theta_hat, h, the stiffness estimate and the recovery's state. Variants exercise what the
steady tick commits: saturated efforts and a rate limit, a wrench in the base frame, a held
point, ticks without a new state and late states, the stiffness estimate off, an episode of the
recovery, a user's path.
"""
from __future__ import annotations

from hybrid_force_controller.core.config.params import build_params
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.arm7 import panda_model, panda_scenario
from hybrid_force_controller.core.offline.scenario import ScenarioConfig
from hybrid_force_controller.core.runtime import tick_kernels
from hybrid_force_controller.core.runtime.controller_runtime import ControllerRuntime
from hybrid_force_controller.tools.offline_bench import recorded_stream
import numpy as np
import pytest

REL = 1e-12
FIELDS = ('tau', 'x_W', 'x_d_W', 'f_W', 'f_d_W', 'e_W', 'theta_hat', 'k_hat', 'xdot_d_W', 'n_W')


@pytest.fixture(scope='module')
def panda() -> RobotModel:
    return panda_model()


def _stream(model, cfg) -> list:
    """Return the (t, q, qdot, F_S) the controller of ``cfg``'s closed loop received."""
    return recorded_stream(model, cfg, path=False)[0]


def _runtimes(model, cfg, extra: dict) -> list[ControllerRuntime]:
    theta0 = (model.theta_nominal * np.asarray(cfg.theta_hat0_scale)).tolist()
    return [ControllerRuntime(model, build_params(model, {
        **cfg.overrides, 'theta_hat0': theta0, 'tick_impl': impl, **extra}))
        for impl in ('python', 'compiled')]


def _same(a, b, what: str) -> None:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    assert a.shape == b.shape, what
    ok = np.isfinite(a)
    assert np.array_equal(ok, np.isfinite(b)), what
    scale = max(np.abs(a[ok]).max(initial=0.0), 1.0)
    assert np.all(np.abs(a[ok] - b[ok]) <= REL * scale), (what, np.abs(a[ok] - b[ok]).max())


def _replay(model, stream, runtimes, base_frame=False, hold_at=None, stale_every=0,
            skip_every=0, path: dict | None = None) -> None:
    """Feed both runtimes the same inputs and ticks (and ``path``'s plan); compare outputs."""
    names = list(model.joint_names)
    for k, (t, q, qdot, F_S) in enumerate(stream):
        if path and t >= path['t']:
            for rt in runtimes:
                rt.on_path(path['plan'], 1)
            path = None
        if skip_every and k % skip_every == 0:
            continue  # a late state: the next one comes 2 periods after the last
        frame, F = model.end_effector_link, F_S
        if base_frame:
            frame, F = model.base_link, model.kinematics(q, qdot).R_W_ee.dot(F_S)
        for rt in runtimes:
            if hold_at is not None and k == hold_at:
                rt.on_reference(rt.reference(t).x_d_W + np.array([0.01, 0.0, 0.0]))
            rt.on_joint_state(names, q, qdot, t)
            rt.on_wrench(frame, F, t)
        repeats = 2 if stale_every and k % stale_every == 0 else 1
        for r in range(repeats):  # a second tick on the same state: nothing new to integrate
            py, nb = (rt.tick(t + 2e-4 * r) for rt in runtimes)
            assert (py.mode, py.status, py.in_contact) == (nb.mode, nb.status, nb.in_contact), k
            assert (py.tau is None) == (nb.tau is None), k
            for name in FIELDS:
                a = getattr(py, name)
                if a is not None:
                    _same(a, getattr(nb, name), f'{name} at state {k}')


def _assert_same_state(py: ControllerRuntime, nb: ControllerRuntime) -> None:
    assert py.counters == nb.counters
    assert (py.mode, py.status) == (nb.mode, nb.status)
    _same(py.ctrl.theta_hat, nb.ctrl.theta_hat, 'theta_hat')
    _same([py.ctrl.h, py._stiffness.k_hat, py.ctrl.k_s], [nb.ctrl.h, nb._stiffness.k_hat,
                                                          nb.ctrl.k_s], 'h, k_hat, k_s')
    assert py.recovery.counts == nb.recovery.counts
    assert py.recovery.has_trusted == nb.recovery.has_trusted
    _same(py.recovery.trusted, nb.recovery.trusted, 'trusted theta_hat')
    for part, names in (('_motion', ('x_seen', 'r_n', 'rdot_n')),
                        ('_clock', ('t_tick', 't_used', 't0')), ('_contact', ('active',))):
        a, b = getattr(py, part), getattr(nb, part)
        _same([getattr(a, n) for n in names], [getattr(b, n) for n in names], f'{part} {names}')
    _same(py._in.filter.value, nb._in.filter.value, 'the force filter')


CASES = {
    'paper': ({}, {}),
    'paper, efforts saturated and rate-limited': ({'effort_limits': [100.0, 2.5],
                                                   'max_effort_rate': 0.003}, {}),
    'paper, wrench in the base frame': ({}, {'base_frame': True}),
    'paper, no stiffness estimate': ({'stiffness_estimation': False}, {}),
    'paper, a held point': ({}, {'hold_at': 1500}),
    'paper, stale ticks and late states': ({'max_integration_dt': 0.0015},
                                           {'stale_every': 7, 'skip_every': 11}),
}


@pytest.mark.parametrize('case', list(CASES))
def test_paper_ticks_agree_with_the_reference(case):
    """And most of the compiled runtime's ticks were steady ones; the reference has none."""
    extra, how = CASES[case]
    model = RobotModel.from_urdf()
    cfg = ScenarioConfig(duration=3.0, theta_hat0_scale=0.5)
    py, nb = _runtimes(model, cfg, extra)
    _replay(model, _stream(model, cfg), (py, nb), **how)
    _assert_same_state(py, nb)
    assert py._steady is None and nb._steady.ticks >= 0.8 * nb.counters['ticks']
    if 'saturated' in case:
        assert nb.counters['saturated_ticks'] > 100


@pytest.mark.parametrize('with_path', [False, True], ids=['line', 'a square path'])
def test_panda_ticks_agree_with_the_reference(panda, with_path):
    """And the path's ticks are steady ones: its clock advanced as the reference's."""
    cfg = panda_scenario(panda, 2.0)
    stream, sent = recorded_stream(panda, cfg, path=with_path)  # a square from 0.5 s on
    py, nb = _runtimes(panda, cfg, {})
    _replay(panda, stream, (py, nb), path=sent)
    _assert_same_state(py, nb)
    assert nb._steady.ticks >= 0.8 * nb.counters['ticks']
    if with_path:
        a, b = py._motion.path, nb._motion.path
        _same([a.sigma, a.rho, a.rho_rate], [b.sigma, b.rho, b.rho_rate], 'the path clock')
        assert b.sigma > 0.5 and a.progress() == b.progress()


def test_an_episode_runs_steady_ticks_with_theta_hat_held():
    """A fault episode (the contact lost, then found) holds theta_hat in either tick."""
    model = RobotModel.from_urdf()
    cfg = ScenarioConfig(duration=3.0, theta_hat0_scale=0.5)
    stream = _stream(model, cfg)
    py, nb = _runtimes(model, cfg, {})
    lifted = [(t, q, qd, F * 0.0 if 1.0 <= t < 1.1 else F) for t, q, qd, F in stream]
    _replay(model, lifted, (py, nb))
    _assert_same_state(py, nb)
    assert nb.recovery.counts['contact_loss'] >= 1 or nb.counters['approach_entries'] >= 1


def test_a_tick_that_is_not_steady_changes_nothing():
    """The tool pulled off: the steady tick declines; the reference's tick runs from there."""
    model = RobotModel.from_urdf()
    cfg = ScenarioConfig(duration=1.5, theta_hat0_scale=0.5)
    stream = _stream(model, cfg)
    rt = _runtimes(model, cfg, {})[1]
    names = list(model.joint_names)
    for t, q, qdot, F_S in stream[:-1]:
        rt.on_joint_state(names, q, qdot, t)
        rt.on_wrench(model.end_effector_link, F_S, t)
        rt.tick(t)
    t, q, qdot, F_S = stream[-1]
    assert rt.mode.name == 'RUNNING' and rt.in_contact
    rt.on_joint_state(names, q, qdot, t)
    rt.on_wrench(model.end_effector_link, -12.0 * F_S, t)  # pulled off: not touching
    before = (dict(rt.counters), rt._in.filter.value.copy(), rt._clock.t_used, rt.ctrl.h,
              rt.ctrl.theta_hat.copy(), rt._steady.ticks)
    assert rt._steady.tick(t) is None
    after = (dict(rt.counters), rt._in.filter.value.copy(), rt._clock.t_used, rt.ctrl.h,
             rt.ctrl.theta_hat.copy(), rt._steady.ticks)
    assert before[0] == after[0] and before[2:4] == after[2:4] and before[5] == after[5]
    assert np.array_equal(before[1], after[1]) and np.array_equal(before[4], after[4])
    assert rt._in._new_wrench  # the reference's tick filters it
    out = rt.tick(t)
    assert rt.counters['ticks'] == before[0]['ticks'] + 1 and out.tau is not None
    assert not np.array_equal(rt._in.filter.value, before[1])


def test_the_workspace_holds_every_scalar_the_kernels_write():
    assert tick_kernels.N_SC >= len(tick_kernels.SC)
    n, m = 7, 3
    offsets = tick_kernels.layout(n, m)
    assert offsets[1] == tick_kernels.N_SC and list(offsets) == sorted(offsets)
    assert offsets[15] - offsets[14] == 2 * n and offsets[12] - offsets[11] == n * n


def test_the_kernels_read_as_cached_once_compiled():
    """What the node reads to say it compiles the tick on a first start (kernels imported)."""
    from hybrid_force_controller.core.runtime.steady_tick import kernels_cached
    assert kernels_cached()
