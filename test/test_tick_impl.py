"""
The compiled tick against the Python reference (issue 33, item 2; law/tick_impl.py, kernels.py).

Step by step, each kernel against its reference on the same inputs: the task inverse of the
Panda (its 3-row and 6-row tasks), the paper's 2 x 2 arm and a square 3 x 3 one, away from a
singularity and damped near one; eq. (5)'s effort and eq. (26)'s update. Then whole closed loops
with ``tick_impl`` python and compiled: the paper's scenario, the Panda, a moving normal (a
sphere), a path (the Panda's square) and a fault episode (the surface falls away 3 cm), whose
every logged effort, position and theta_hat must agree to a relative 1e-12 of the series' size.
"""
from __future__ import annotations

import math

from helpers.offline import move_surface, N_TOLD, SURFACES
from hybrid_force_controller.core.config.params import build_params, ParameterValidationError
from hybrid_force_controller.core.law.control_law import HybridForceController
from hybrid_force_controller.core.law.tick_impl import CompiledTick, make_tick, PythonTick
from hybrid_force_controller.core.model.robot_model import RobotModel
from hybrid_force_controller.core.offline.arm7 import (panda_model, PANDA_Q0, panda_scenario,
                                                       square_path_event)
from hybrid_force_controller.core.offline.engine import Event
from hybrid_force_controller.core.offline.scenario import run_scenario, ScenarioConfig
import numpy as np
import pytest

# the agreement asked (issue 33). Measured: 2e-15 step by step; in the closed loops the rounding
# grows with the run, to 3e-13 of the force on the sphere at 4 s (8e-13 at 6 s), 5e-13 in the
# moment mode's path: the runs are cut to keep 2-3 times of margin (on the last sessions'
# machines; the forces are now compared as depths, assert_same_run)
REL = 1e-12
FORCES = ('f_W', 'f_true_W')  # the plant's k times a depth (assert_same_run)
RNG = np.random.default_rng(33)


@pytest.fixture(scope='module')
def panda() -> RobotModel:
    return panda_model()


@pytest.fixture(scope='module')
def ticks() -> tuple[PythonTick, CompiledTick]:
    return PythonTick(7), CompiledTick(7)


def close(a, b, rel: float = REL) -> bool:
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= rel * max(np.abs(a).max(), 1.0)))


def assert_same_reference(ticks, M_inv, J, sigma0) -> bool:
    """Both joint references agree on random r, rdot; return whether they damped."""
    m = J.shape[0]
    r, rdot, Jdot = RNG.normal(size=m), RNG.normal(size=m), RNG.normal(size=J.shape)
    py, nb = (t.joint_reference(lambda: M_inv, J, Jdot, r, rdot, sigma0) for t in ticks)
    assert py[4] == nb[4]
    assert (py[1] is None) == (nb[1] is None)
    for a, b in zip(py[:4], nb[:4]):
        assert b is None or close(a, b)
    return py[4]


@pytest.mark.parametrize('rows', ['J6', 'J_ee'])
def test_panda_inverse_matches(panda, ticks, rows):
    """The Panda's redundant inverse, N and joint reference: at random poses and damped."""
    damped = set()
    for k in range(20):
        q = np.array(PANDA_Q0) + RNG.normal(scale=0.4, size=7)
        kin = panda.kinematics(q, np.zeros(7))
        sigma0 = 0.05 if k % 2 else 2.0  # 2.0: above every pose's sigma, so damped
        damped.add(assert_same_reference(ticks, panda.inertia_inverse(q), getattr(kin, rows),
                                         sigma0))
    assert damped == {False, True}


@pytest.mark.parametrize('size', [2, 3])
def test_square_inverse_matches(ticks, size):
    """A square J (the paper's 2 x 2, a 3 x 3): inverted, and damped, alike."""
    damped = set()
    for k in range(20):
        J = RNG.normal(size=(size, size))
        damped.add(assert_same_reference(ticks, None, J, 0.3 if k % 2 else 0.0))
    assert True in damped and False in damped


def test_singular_square_j_is_refused_by_both(ticks):
    """The paper's arm stretched out, undamped (singular_sigma 0): both raise LinAlgError."""
    J = np.array([[1.0, 0.5], [2.0, 1.0]])
    for t in ticks:
        with pytest.raises(np.linalg.LinAlgError):
            t.joint_reference(lambda: None, J, J, np.ones(2), np.ones(2), 0.0)


def test_square_sigma_of_a_3x3_decides_alike(ticks):
    """The 3 x 3 smallest singular value (eigvalsh against a closed form) damps at one sigma."""
    J = np.diag([1.0, 0.5, 0.2])
    for sigma0, damped in ((0.19, False), (0.21, True)):
        for t in ticks:
            assert t.joint_reference(lambda: None, J, J, np.ones(3), np.ones(3), sigma0)[4] \
                == damped


@pytest.mark.parametrize('rot, tau_0, null', [(False, False, False), (True, True, True),
                                              (False, True, True)])
def test_effort_and_adaptation_match(ticks, rot, tau_0, null):
    """Eq. (5)'s effort with each optional term, eq. (26)'s update at every weight's branch."""
    n, p = 7, 12
    Y = RNG.normal(size=(n, p))
    args = (Y, RNG.normal(size=p), RNG.normal(size=n) if tau_0 else None,
            RNG.normal(size=(3, n)), RNG.normal(size=3), RNG.normal(size=(3, n)) if rot else None,
            RNG.normal(size=3) if rot else None, RNG.normal(size=(n, n)) if null else None,
            RNG.normal(size=n), 2.0)
    (tau_py, ok_py), (tau_nb, ok_nb) = (t.effort(*args) for t in ticks)
    assert ok_py and ok_nb and close(tau_py, tau_nb)
    G = np.diag(RNG.uniform(0.5, 2.0, p)) + 0.01 * np.ones((p, p))
    theta = RNG.normal(size=p)
    for e_scale, dead in ((1e-3, 0.0), (1.0, 0.0), (1e-3, 1e-2), (0.05, 1e-3)):
        e = RNG.normal(size=3) * e_scale
        a = (theta, G, Y, RNG.normal(size=n), e, 1500.0, 0.1, dead, 1e-3, theta - 1e-4,
             theta + 1e-4)
        assert close(ticks[0].adapt(*a), ticks[1].adapt(*a))


def test_non_finite_effort_is_flagged_by_both(ticks):
    Y = np.ones((7, 3))
    args = (Y, np.array([1.0, np.nan, 0.0]), None, np.zeros((3, 7)), np.zeros(3), None, None,
            None, np.zeros(7), 0.0)
    assert not ticks[0].effort(*args)[1] and not ticks[1].effort(*args)[1]


class _Spy:
    """The kernels module, each call of its three kernels counted."""

    def __init__(self, kernels) -> None:
        self._k, self.calls = kernels, []

    def __getattr__(self, name):
        def call(*args):
            self.calls.append(name)
            return getattr(self._k, name)(*args)
        return call


def test_the_warm_up_calls_every_kernel_before_any_tick(panda, monkeypatch):
    """Numba finishes a kernel on its first call (ms): the law makes it when it is built."""
    tick = CompiledTick(7)
    tick._k, tick._s = spy, spy_s = _Spy(tick._k), _Spy(tick._s)
    tick.warm_up(panda)
    assert sorted(set(spy.calls)) == ['adapt', 'effort', 'task_reference']
    assert spy.calls.count('task_reference') == 2  # the 3-row and the 6-D task
    # the reference, and the steady step (step_kernels.py)
    assert spy_s.calls == ['reference_rows', 'law_front', 'law_back']
    warmed = []
    monkeypatch.setattr(CompiledTick, 'warm_up', lambda self, model: warmed.append(model))
    HybridForceController(panda, build_params(panda, {}).law)
    assert warmed == [panda]


def test_no_python_runs_inside_a_kernel_call(panda, ticks, monkeypatch):
    """
    The kernels fill their callers' arrays: none is boxed, so no Python frame runs in a call.

    Boxing a returned array unpickles its dtype in Python (numba.core.serialize); a Ctrl-C that
    landed there became a SystemError out of the kernel instead of a KeyboardInterrupt.
    """
    import numba.core.serialize as serialize
    calls = []
    real = serialize._numba_unpickle
    monkeypatch.setattr(serialize, '_numba_unpickle', lambda *a: calls.append(1) or real(*a))
    q = np.array(PANDA_Q0)
    kin = panda.kinematics(q, np.zeros(7))
    theta = np.array(panda.theta_nominal)
    tick = ticks[1]
    for J, Jdot, J_w in ((kin.J_ee, kin.Jdot_ee, None), (kin.J6, kin.Jdot6, kin.J_w)):
        m = J.shape[0]
        _, N, qdot_r, qddot_r, _ = tick.joint_reference(lambda: panda.inertia_inverse(q), J, Jdot,
                                                        np.ones(m), np.ones(m), 0.1)
        Y_q, tau_0 = panda.regressor_affine(q, q, qdot_r, qddot_r)
        assert tick.effort(Y_q, theta, tau_0, kin.J_ee, np.ones(3), J_w,
                           None if J_w is None else np.ones(3), N, q, 1.0)[1]
        tick.adapt(theta, np.eye(theta.size), Y_q, q, np.ones(3), 1.0, 0.1, 0.0, 1e-3,
                   theta - 1.0, theta + 1.0)
    law = HybridForceController(panda, build_params(panda, {}).law)
    d = law._d
    tau = tick.law_step(panda, q, q, kin, (np.ones(3),) * 3, np.ones(3), d.G, (0.1, 0.0),
                        d.gains, d.Gamma_inv, theta, 1e-3, True)[0]
    assert tau is not None and np.all(np.isfinite(tau))
    rows = np.zeros((3, 3))
    tick.reference_rows(np.ones((3, 3, 3)), 1.0, True, rows, 0.1, 0.0, 0.5, np.ones((2, 3)),
                        0.0, 0.5, np.ones((2, 3)), rows)
    assert np.all(np.isfinite(rows))
    assert calls == []


@pytest.mark.parametrize('arm', ['paper', 'panda', 'panda_payload'])
def test_steady_step_matches_the_reference(panda, arm):
    """
    The law's steady step in two kernels (step_kernels.py) is control_law.step's numpy.

    Each step on a random state, both laws carried on from their own last one: tau, e, theta_hat
    and h agree, with adaptation, frozen (``adapt`` False), without a new state (dt 0), with the
    known part tau_0 (``payload``) and without it, and near a singular pose (damped, no
    adaptation: the 2-link arm stretched out).
    """
    model = {'paper': RobotModel.from_urdf(), 'panda': panda,
             'panda_payload': panda_model('payload')}[arm]
    py, nb = (HybridForceController(model, build_params(
        model, {'singular_sigma': 0.05, 'tick_impl': impl}).law)
        for impl in ('python', 'compiled'))
    q0 = np.array(PANDA_Q0) if model.n == 7 else np.array([0.4, 1.1])
    rng = np.random.default_rng(7)
    damped = []
    for k in range(40):
        q = q0 + 0.2 * rng.normal(size=model.n)
        if model.n == 2 and k % 4 == 3:
            q[1] = 1e-3  # stretched out: J near singular, the inverse damped
        qdot, f_W = rng.normal(size=model.n), rng.normal(size=3) * 5.0
        ref = tuple(rng.normal(size=3) * s for s in (0.5, 0.1, 0.1))
        dt, adapt = (1e-3, 0.0)[k % 5 == 4], k % 7 != 6
        a, b = (law.step(q, qdot, f_W, ref, dt, adapt=adapt, r_bias=(0.01, -0.02))
                for law in (py, nb))
        damped.append(nb.damped)
        assert py.damped == nb.damped
        for x, y in ((a.tau, b.tau), (a.e, b.e), (py.theta_hat, nb.theta_hat)):
            assert close(x, y), (k, float(np.abs(x - y).max()))
        assert abs(py.h - nb.h) <= REL * max(abs(py.h), 1.0)
    assert any(damped) == (model.n == 2) and not all(damped)


class _Path:
    """A path's rows (reference.py: any object with rows(tau))."""

    @staticmethod
    def rows(tau: float) -> np.ndarray:
        return np.array([[0.5 + 0.1 * tau, 0.2, 0.3], [0.1, 0.0, 0.0], [0.0, 0.0, 0.0]])


def test_reference_rows_match_the_reference():
    """
    The compiled reference (step_kernels.reference_rows) is BlendedReference.rows' numpy.

    The sine blending in from the arm, a correction (a stall) with its velocity and position
    parts, a held point and a path, each blending in: the rows agree at every 7 ms over 3 s.
    """
    from hybrid_force_controller.core.law import reference as ref_mod
    from hybrid_force_controller.core.law import step_kernels
    assert step_kernels.CORRECT_VEL_S == ref_mod.CORRECT_VEL_S
    sine = ref_mod.SineReference(np.array([1.0, 0.0, 0.2]), np.array([0.1, 0.05, 0.0]), 1.3)
    n = np.array([0.0, 0.0, 1.0])
    py, nb = ref_mod.BlendedReference(sine, n, 0.5), ref_mod.BlendedReference(sine, n, 0.5)
    nb.kernel = step_kernels.reference_rows
    events = {0.0: lambda r, t: r.start_from(t, np.array([1.1, 0.05, 0.2]), np.ones(3)),
              0.8: lambda r, t: r.correct_from(t, np.array([1.2, 0.0, 0.2]), -np.ones(3)),
              1.6: lambda r, t: r.switch(t, x_hold_W=np.array([0.9, 0.1, 0.2])),
              2.2: lambda r, t: r.switch(t, path=_Path(), blend_s=0.3)}
    cases = set()
    for k in range(430):
        tau = k * 0.007
        for t_event, act in events.items():
            if t_event <= tau < t_event + 0.007:
                act(py, tau)
                act(nb, tau)
        a, b = py.rows(tau), nb.rows(tau)
        assert a.shape == b.shape == (3, 3) and close(a, b), (tau, float(np.abs(a - b).max()))
        cases.add((py.path is not None, py.x_hold_W is not None, tau - py.tau_b < py._tb,
                   0.0 <= tau - py._corr_tau < 0.25))
    assert len(cases) >= 5  # sine, blending, correcting, held, path


_STIFFNESS_STATE = ('k_hat', 'k_hat_std', 'valid', 'k_s', 'k_s_log_rate', 'excited',
                    'excitation_n', 'saturated', 'samples_used', 'samples_rejected', 'restarts',
                    'changes', '_x_f', '_x_last', '_x_ref', '_x_bar', '_b', '_r_uu', '_r_ub',
                    '_r_bb', '_cusum', '_w', '_s2_sum', '_held')


def _same_estimates(py, nb, where) -> None:
    for name in _STIFFNESS_STATE:
        a, b = getattr(py, name), getattr(nb, name)
        if a is None or isinstance(a, (bool, int, tuple)):
            ok = a == b if not isinstance(a, tuple) else b is not None and close(a, b)
        else:
            ok = close(a, b)
        assert ok, (where, name, a, b)


@pytest.mark.parametrize('settings', [{}, {'k_hat0': 800.0, 'change_force': 0.0,
                                           'k_s_time_constant': 0.0, 'force_filter_hz': 0.0},
                                      {'enabled': False, 'time_constant': 0.5}])
def test_stiffness_kernels_match_the_reference(settings):
    """
    The compiled stiffness estimate (stiffness_kernels.py) is stiffness.py's, sample by sample.

    A contact loading and oscillating on a 2000 N/m surface, spikes of 1 cm after the estimate
    is valid (S10), a NaN sample, the surface stiffening to 3000 N/m (S9), a contact loss, and
    the rare calls (re-anchoring, new settings, a k_s command set, a filter restart) made on
    both: every attribute of the estimate agrees after every call.
    """
    from hybrid_force_controller.core.law import stiffness as ref_mod, stiffness_kernels as sk
    from hybrid_force_controller.core.law.stiffness_compiled import CompiledStiffnessEstimator
    assert (sk.MIN_SAMPLES, sk.MAX_NORMAL_SPEED, sk.CHANGE_TIME) == (
        ref_mod.MIN_SAMPLES, ref_mod.MAX_NORMAL_SPEED, ref_mod.CHANGE_TIME)
    config = ref_mod.StiffnessConfig(**settings)
    py, nb = ref_mod.StiffnessEstimator(config), CompiledStiffnessEstimator(config, sk)
    rng = np.random.default_rng(5)
    rare = {2500: lambda e: e.re_anchor(),
            3500: lambda e: e.reconfigure(ref_mod.StiffnessConfig(
                **{**settings, 'valid_tol': 0.1})),
            4200: lambda e: e.set_k_s_command(2500.0),
            4600: lambda e: e.forget_data(restart_filter=True), 5000: lambda e: e.restart()}
    seen = set()
    for k in range(6000):
        t, dt = k * 1e-3, 1e-3 * (1.0 + 0.1 * rng.uniform(-1.0, 1.0))
        k_true, touching = (2000.0 if t < 3.0 else 3000.0), not 5.3 <= t < 5.5
        x_n = 0.002 + 0.0005 * math.sin(2 * math.pi * 2.0 * t) if touching else -0.01
        f_n = k_true * x_n + rng.normal(0.0, 0.01) if touching else 0.0
        if k % 401 == 400:
            x_n += 0.01  # a spike
        if k == 1500:
            f_n = math.nan
        if k in rare:
            rare[k](py), rare[k](nb)
        for est in (py, nb):
            est.update(f_n, x_n, dt, touching)
        _same_estimates(py, nb, (k, 'update'))
        assert py.k_s_command(dt) == pytest.approx(nb.k_s_command(dt), rel=REL, abs=0.0)
        _same_estimates(py, nb, (k, 'k_s'))
        seen |= {name for name in ('valid', 'excited', 'saturated') if getattr(py, name)}
        seen |= {'held'} if py._held else set()
    assert {'valid', 'excited', 'held'} <= seen and py.samples_rejected >= 10
    assert py.restarts == 1 + py.changes and (py.changes >= 1) == (config.change_force > 0.0)


def test_a_stale_cache_of_the_step_kernels_is_dropped(tmp_path):
    """
    Numba's cache sees only its own file: step_kernels' is dropped when kernels.py is newer.

    Only that module's cache files go, and only when one is older than the dependency.
    """
    import os
    from hybrid_force_controller.core.law.step_kernels import drop_stale_cache
    module, dependency = tmp_path / 'step_kernels.py', tmp_path / 'kernels.py'
    cache = tmp_path / '__pycache__'
    cache.mkdir()
    mine = [cache / 'step_kernels.law_back-90.py311.nbi',
            cache / 'step_kernels.law_back-90.py311.1.nbc']
    other = cache / 'kernels.effort-200.py311.nbi'
    for path in (module, dependency, *mine, other):
        path.write_text('x')
    for path, when in ((dependency, 1000), (mine[0], 2000), (mine[1], 2000), (other, 500)):
        os.utime(path, (when, when))
    assert drop_stale_cache(module, dependency) == [] and all(p.exists() for p in mine)
    os.utime(dependency, (3000, 3000))  # kernels.py edited after the cache was written
    assert drop_stale_cache(module, dependency) == sorted(mine)
    assert not any(p.exists() for p in mine) and other.exists()
    assert drop_stale_cache(module, dependency) == []  # nothing left to drop


def test_tick_impl_is_validated():
    model = RobotModel.from_urdf()
    assert build_params(model, {}).law.tick_impl == 'compiled'
    assert build_params(model, {'tick_impl': 'python'}).law.tick_impl == 'python'
    with pytest.raises(ParameterValidationError, match='tick_impl must be one of'):
        build_params(model, {'tick_impl': 'cython'})
    with pytest.raises(ValueError, match='tick_impl'):
        make_tick('fast', 2)
    assert isinstance(make_tick('compiled', 2), CompiledTick)
    assert 'compiled: numba kernels' in make_tick('compiled', 2).note


# ---------------------------------------------------------------- closed loops, both ticks
def _both(run) -> tuple:
    return run('python'), run('compiled')


def assert_same_run(py, nb) -> None:
    """
    Every logged series of two closed loops agrees to REL of its size.

    The forces are the plant's ``k (x - x_s)``: a depth of a millimetre taken as the difference
    of two positions of about a metre, so an ulp of the position is 1e-13 of a small force.
    They are compared as that depth, ``f / k``, to REL of the position's size (s55a: the fault
    episode's f_W differed by 2.3e-12 N, 1.7e-12 of its 1.3 N, with x_W within 1e-15).
    """
    assert py.ticks == nb.ticks and py.mode == nb.mode
    for name in ('tau', 'x_W', 'f_W', 'f_true_W', 'theta_hat', 'n_hat_W'):
        a, b = getattr(py, name), getattr(nb, name)
        ok = np.isfinite(a)
        assert np.array_equal(ok, np.isfinite(b)), name
        if name in FORCES:
            a, b = a / py.k_true, b / py.k_true  # depths, m
            scale = max(np.abs(a[ok]).max(), np.abs(py.x_W).max(), 1.0)
            assert np.all(np.abs(a[ok] - b[ok]) <= REL * scale), \
                (name, float(np.abs(a[ok] - b[ok]).max()))
            continue
        assert close(a[ok], b[ok]), (name, float(np.abs(a[ok] - b[ok]).max()))


def test_paper_scenario_alike():
    """And the compiled law's ticks ran its steady step (step_kernels.py) in the force loop."""
    model = RobotModel.from_urdf()
    py, nb = _both(lambda impl: run_scenario(ScenarioConfig(
        duration=6.0, theta_hat0_scale=0.5, overrides={'tick_impl': impl}), model))
    assert_same_run(py, nb)
    steady = nb.runtime.ctrl._tick.steady_steps
    assert steady >= 0.95 * nb.ticks and py.runtime.ctrl._tick.steady_steps == 0


def test_panda_alike(panda):
    assert_same_run(*_both(lambda impl: run_scenario(
        panda_scenario(panda, 4.0, overrides={'tick_impl': impl}), panda)))


def test_panda_path_and_moment_alike(panda):
    """The Panda's square on a tilted plane, the tool held square by the moments (6-D)."""
    def run(impl):
        cfg = panda_scenario(panda, 3.0, events=[square_path_event(1.0, 0.04, {})],
                             surface_normal=(0.0, math.sin(0.3), -math.cos(0.3)),
                             overrides={'ref_amplitude': [0.0, 0.0, 0.0], 'tick_impl': impl,
                                        'n': [0.0, 0.0, -1.0], 'n_estimation': True,
                                        'orientation_mode': 'moment'})
        return run_scenario(cfg, panda)
    assert_same_run(*_both(run))


def test_moving_normal_alike(panda):
    """helpers.offline.panda_run's sphere (a learnt normal, sensor noise), cut to 4 s."""
    def run(impl):
        cfg = panda_scenario(panda, 4.0, events=[square_path_event(1.0, 0.1, {})],
                             noise_sigma=0.05, seed=1, **SURFACES['sphere'],
                             overrides={'n': N_TOLD, 'n_estimation': True, 'tick_impl': impl,
                                        'ref_amplitude': [0.0, 0.0, 0.0]})
        return run_scenario(cfg, panda)
    assert_same_run(*_both(run))


def test_fault_episode_alike():
    """The surface falls away 3 cm at 3 s: a contact-loss episode, an approach, contact again."""
    model = RobotModel.from_urdf()
    py, nb = _both(lambda impl: run_scenario(ScenarioConfig(
        duration=5.0, delay_steps=2, overrides={'tick_impl': impl},
        events=[Event(3.0, move_surface(0.03))]), model))
    assert py.runtime.recovery.counts['contact_loss'] == 1  # the episode happened
    assert_same_run(py, nb)
