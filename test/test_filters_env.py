"""Force low-pass filter, elastic surface, wrench frame conversions and the reference."""
from __future__ import annotations

import math

from hybrid_force_controller.core.law.reference import (blend_start, BlendedReference,
                                                        CORRECT_ACCEL, CORRECT_VEL_S, H0_PEAK,
                                                        Reference, SineReference)
from hybrid_force_controller.core.offline.environment import (ElasticSurface,
                                                              f_W_from_sensor_wrench,
                                                              sensor_wrench_from_f_W, SurfaceError)
from hybrid_force_controller.core.runtime.filters import LowPassFilter
import numpy as np
import pytest


DT = 1e-3


def rotation(rng) -> np.ndarray:
    Q, R = np.linalg.qr(rng.normal(size=(3, 3)))
    Q = Q * np.sign(np.diag(R))
    return Q if np.linalg.det(Q) > 0 else -Q


# ---------------------------------------------------------------- LowPassFilter
def test_filter_starts_from_first_finite_sample():
    filt = LowPassFilter(10.0)
    assert not filt.ready
    np.testing.assert_array_equal(filt.value, np.zeros(3))
    u = np.array([0.3, -1.2, 5.0])
    assert filt.update(u, DT)
    assert filt.ready
    np.testing.assert_array_equal(filt.value, u)  # no transient from zero
    filt.update(u, DT)
    np.testing.assert_allclose(filt.value, u, rtol=1e-15)


@pytest.mark.parametrize('bad', [math.nan, math.inf, -math.inf])
def test_filter_skips_non_finite_samples(bad):
    filt = LowPassFilter(10.0)
    assert not filt.update(np.array([bad, 0.0, 0.0]), DT)
    assert not filt.ready  # a bad first sample does not start the filter
    filt.update(np.array([1.0, 2.0, 3.0]), DT)
    filt.update(np.array([2.0, 2.0, 3.0]), DT)
    kept = filt.value.copy()
    assert not filt.update(np.array([0.0, bad, 0.0]), DT)
    np.testing.assert_array_equal(filt.value, kept)
    # and the next good sample continues from the kept output
    a = 1.0 - math.exp(-2 * math.pi * 10.0 * DT)
    filt.update(np.array([2.0, 2.0, 3.0]), DT)
    np.testing.assert_allclose(filt.value, kept + a * (np.array([2.0, 2.0, 3.0]) - kept))


@pytest.mark.parametrize('cutoff_hz', [2.0, 20.0])
def test_filter_step_response_has_first_order_time_constant(cutoff_hz):
    tau = 1.0 / (2 * math.pi * cutoff_hz)
    filt = LowPassFilter(cutoff_hz)
    filt.update(np.zeros(3), DT)
    step = np.array([1.0, -2.0, 0.5])
    n = int(round(5 * tau / DT))
    ys = []
    for _ in range(n):
        filt.update(step, DT)
        ys.append(filt.value[0])
    t = DT * np.arange(1, n + 1)
    np.testing.assert_allclose(ys, 1.0 - np.exp(-t / tau), rtol=0, atol=1e-12)
    k_tau = int(round(tau / DT))
    assert ys[k_tau - 1] == pytest.approx(1 - math.exp(-1), abs=DT / tau)
    np.testing.assert_allclose(filt.value, step * (1 - math.exp(-n * DT / tau)), rtol=1e-12)


def test_filter_handles_changing_dt():
    filt = LowPassFilter(5.0)
    filt.update(np.zeros(3), DT)
    filt.update(np.ones(3), 2e-3)
    a2 = 1 - math.exp(-2 * math.pi * 5.0 * 2e-3)
    assert filt.value[0] == pytest.approx(a2, rel=1e-12)
    filt.update(np.ones(3), 1e-3)
    a1 = 1 - math.exp(-2 * math.pi * 5.0 * 1e-3)
    assert filt.value[0] == pytest.approx(a2 + a1 * (1 - a2), rel=1e-12)


def test_filter_cutoff_zero_passes_through():
    filt = LowPassFilter(0.0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        u = rng.normal(size=3)
        filt.update(u, DT)
        np.testing.assert_array_equal(filt.value, u)


def test_filter_reset_restarts_from_next_sample():
    filt = LowPassFilter(10.0)
    filt.update(np.ones(3), DT)
    filt.reset()
    assert not filt.ready
    filt.update(np.full(3, 7.0), DT)
    np.testing.assert_array_equal(filt.value, np.full(3, 7.0))


# ---------------------------------------------------------------- ElasticSurface
@pytest.fixture
def surface() -> ElasticSurface:
    return ElasticSurface.create(1700.0, [1.0, 1.6, 0.0], [0.0, -1.0, 0.0])


def test_surface_zero_force_outside(surface):
    for p in ([1.0, 1.7, 0.0], [0.5, 1.6000001, 0.3], [1.0, 1.6, 0.0]):  # outside / on it
        np.testing.assert_array_equal(surface.force(np.array(p)), np.zeros(3))
        assert surface.penetration(np.array(p)) <= 0.0


def test_surface_pushes_k_depth_n_inside(surface):
    p = np.array([1.3, 1.6 - 2e-3, 0.1])  # 2 mm into the surface (n = -y)
    assert surface.penetration(p) == pytest.approx(2e-3)
    np.testing.assert_allclose(surface.force(p), 1700.0 * 2e-3 * np.array([0.0, -1.0, 0.0]),
                               rtol=1e-12)
    # tangential displacement does not change the force (frictionless)
    np.testing.assert_allclose(surface.force(p + [0.5, 0.0, -0.2]), surface.force(p),
                               rtol=1e-12)


def test_surface_never_pulls():
    rng = np.random.default_rng(0)
    for _ in range(50):
        n = rng.normal(size=3)
        s = ElasticSurface.create(rng.uniform(10, 1e4), rng.normal(size=3), n)
        p = rng.normal(size=3)
        f = s.force(p)
        assert float(f @ s.n_W) >= 0.0
        np.testing.assert_allclose(np.cross(f, s.n_W), 0.0, atol=1e-9)  # along n only


def test_surface_normalises_normal():
    s = ElasticSurface.create(100.0, [0, 0, 0], [0.0, -3.0, 4.0])
    np.testing.assert_allclose(s.n_W, [0.0, -0.6, 0.8])
    assert np.linalg.norm(s.n_W) == pytest.approx(1.0)


@pytest.mark.parametrize('k', [0.0, -5.0, math.nan, math.inf])
def test_surface_rejects_bad_stiffness(k):
    with pytest.raises(SurfaceError, match='stiffness'):
        ElasticSurface.create(k, [0, 0, 0], [0, -1, 0])


@pytest.mark.parametrize('n', [[0, 0, 0], [1e-12, 0, 0], [math.nan, -1, 0], [0, -1]])
def test_surface_rejects_bad_normal(n):
    with pytest.raises(SurfaceError, match='normal'):
        ElasticSurface.create(100.0, [0, 0, 0], n)


@pytest.mark.parametrize('x0', [[math.nan, 0, 0], [0, math.inf, 0], [0, 0]])
def test_surface_rejects_bad_point(x0):
    with pytest.raises(SurfaceError, match='point'):
        ElasticSurface.create(100.0, x0, [0, -1, 0])


# ---------------------------------------------------------------- wrench conversions
def test_sensor_wrench_conversions_are_inverses():
    rng = np.random.default_rng(0)
    for _ in range(10):
        R = rotation(rng)
        f_W = rng.normal(size=3)
        F = sensor_wrench_from_f_W(R, f_W)
        np.testing.assert_allclose(f_W_from_sensor_wrench(R, F), f_W, atol=1e-14)
        np.testing.assert_allclose(sensor_wrench_from_f_W(R, f_W_from_sensor_wrench(R, F)), F,
                                   atol=1e-14)
        assert np.linalg.norm(F) == pytest.approx(np.linalg.norm(f_W))


def test_sensor_wrench_is_the_reaction_in_the_sensor_frame():
    """The sensor reports the force ON the tool: -f, expressed in the tool frame."""
    R = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # 90 deg about z
    f_W = np.array([0.0, -1.0, 0.0])  # tool pushes along -y (base)
    # the surface pushes the tool along +y (base) = -x of the tool frame
    np.testing.assert_allclose(sensor_wrench_from_f_W(R, f_W), [1.0, 0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(sensor_wrench_from_f_W(np.eye(3), f_W), -f_W)


# ---------------------------------------------------------------- reference
def test_sine_reference_values():
    ref = SineReference(np.array([1.0, 1.6, 0.0]), np.array([0.1, 0.0, 0.0]), 1.0)
    r = ref(math.pi / 2)
    np.testing.assert_allclose(r.x_d_W, [1.1, 1.6, 0.0])
    np.testing.assert_allclose(r.xdot_d_W, [0.0, 0.0, 0.0], atol=1e-16)
    np.testing.assert_allclose(r.xddot_d_W, [-0.1, 0.0, 0.0])


@pytest.mark.parametrize('t', [0.0, 0.4, 1.3, 7.9])
def test_sine_reference_derivatives_match_finite_differences(t):
    ref = SineReference(np.array([1.0, 1.6, 0.2]), np.array([0.1, -0.05, 0.02]), 2.3)
    h = 1e-5
    fd_v = (ref(t + h).x_d_W - ref(t - h).x_d_W) / (2 * h)
    fd_a = (ref(t + h).xdot_d_W - ref(t - h).xdot_d_W) / (2 * h)
    np.testing.assert_allclose(ref(t).xdot_d_W, fd_v, atol=1e-8)
    np.testing.assert_allclose(ref(t).xddot_d_W, fd_a, atol=1e-8)


def _blend_case():
    sine = SineReference(np.array([1.0, 1.6, 0.0]), np.array([0.1, 0.0, 0.0]), 1.0)
    offset = np.array([-0.21, 0.0, 0.0])
    return sine, offset, 2.0


def test_blend_start_at_t0_is_reference_plus_offset():
    sine, offset, tb = _blend_case()
    r = blend_start(sine(0.0), offset, 0.0, tb)
    np.testing.assert_allclose(r.x_d_W, sine(0.0).x_d_W + offset)
    np.testing.assert_allclose(r.xdot_d_W, sine(0.0).xdot_d_W)  # the blend adds no velocity
    np.testing.assert_allclose(r.xddot_d_W, sine(0.0).xddot_d_W)


def test_blend_start_is_continuous_at_both_ends():
    sine, offset, tb = _blend_case()
    eps = 1e-7
    # t = t_blend: from inside the blend to the plain reference
    inside = blend_start(sine(tb - eps), offset, tb - eps, tb)
    at = blend_start(sine(tb), offset, tb, tb)
    for a, b in zip(inside, at):
        np.testing.assert_allclose(a, b, atol=1e-5)
    for a, b in zip(at, sine(tb)):
        np.testing.assert_array_equal(a, b)
    # t = 0: just after the start the output is x_d + offset (continuous)
    after = blend_start(sine(eps), offset, eps, tb)
    np.testing.assert_allclose(after.x_d_W, sine(0.0).x_d_W + offset, atol=1e-7)
    np.testing.assert_allclose(after.xdot_d_W, sine(0.0).xdot_d_W, atol=1e-6)


def test_blend_start_derivatives_match_finite_differences():
    sine, offset, tb = _blend_case()
    h = 1e-6
    for t in (0.1, 0.7, 1.0, 1.6, 1.95):
        r = blend_start(sine(t), offset, t, tb)
        rp = blend_start(sine(t + h), offset, t + h, tb)
        rm = blend_start(sine(t - h), offset, t - h, tb)
        np.testing.assert_allclose(r.xdot_d_W, (rp.x_d_W - rm.x_d_W) / (2 * h), atol=1e-7)
        np.testing.assert_allclose(r.xddot_d_W, (rp.xdot_d_W - rm.xdot_d_W) / (2 * h), atol=1e-6)


def test_blend_start_midway_and_disabled():
    sine, offset, tb = _blend_case()
    mid = blend_start(sine(1.0), offset, 1.0, tb)
    np.testing.assert_allclose(mid.x_d_W, sine(1.0).x_d_W + 0.5 * offset)  # b(1/2) = 1/2
    ref = sine(0.3)
    assert blend_start(ref, offset, 0.3, 0.0) is ref  # t_blend = 0: no blend
    assert isinstance(blend_start(ref, offset, 0.3, 1.0), Reference)


def test_blended_reference_equals_blend_start_of_the_sine():
    """The run's reference (blend on stacked rows) equals blend_start of the sine, to rounding."""
    sine = SineReference(np.array([1.0, 1.6, 0.2]), np.array([0.1, -0.05, 0.02]), 2.3)
    ref = BlendedReference(sine, np.array([0.0, -1.0, 0.0]), 2.0)
    ref.start_from(0.5, np.array([0.8, 1.7, 0.1]), np.array([0.3, -0.2, 0.05]))
    for tau in (0.2, 0.5, 0.9, 1.7, 2.49, 2.5, 3.0):
        expected = blend_start(sine(tau), ref.dp_W, tau - 0.5, 2.0, ref.dv_W)
        for a, b in zip(ref(tau), expected):
            np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-15)
    for a, b in zip(ref(2.5), sine(2.5)):  # the blend is over: the sine itself
        np.testing.assert_array_equal(a, b)


def _paper_start() -> BlendedReference:
    """Return the paper's reference, blending from the tool's start (0.79 m, at rest)."""
    sine = SineReference(np.array([1.0, 1.6, 0.0]), np.array([0.1, 0.0, 0.0]), 1.0)
    ref = BlendedReference(sine, np.array([0.0, -1.0, 0.0]), 2.0)
    ref.start_from(0.0, np.array([0.7926, 1.6, 0.0]), np.zeros(3))
    return ref


def test_a_correction_from_the_reference_itself_leaves_the_blend_under_way():
    """
    Stalls during the start-up blend, the arm on the reference: correct_from changes nothing.

    Negative control: restarting the blend from the arm (start_from, what stalls did before)
    carried the blend's 0.2 m/s into a fresh 2 s and took the reference past the sine's end
    (1.1 m), toward the arm's full reach (|x| = 2 m at 1.19 m).
    """
    taus = np.arange(0.0, 4.0, 0.01)
    plain, corrected, restarted = _paper_start(), _paper_start(), _paper_start()
    for tau0 in (0.8, 1.0, 1.35, 1.8):
        for ref, how in ((corrected, 'correct_from'), (restarted, 'start_from')):
            now = ref(tau0)
            getattr(ref, how)(tau0, now.x_d_W, now.xdot_d_W)
    for tau in taus:
        for a, b in zip(corrected(tau), plain(tau)):
            np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-12)
    assert max(plain(tau).x_d_W[0] for tau in taus) < 1.1
    assert max(restarted(tau).x_d_W[0] for tau in taus) > 1.12


def test_a_correction_starts_at_the_arm_and_ends_on_the_course():
    """
    correct_from: the arm's position and velocity at its start, the reference's acceleration.

    The velocity's offset is gone after CORRECT_VEL_S and carries the reference at most 16/81
    CORRECT_VEL_S |dv| (the peak of H1); the position's after T_p = sqrt(2 H0_PEAK |dp| /
    CORRECT_ACCEL), accelerating at most CORRECT_ACCEL / 2.
    """
    tau0, dv = 1.0, np.array([0.5, 0.0, 0.0])
    for dp in (np.zeros(3), np.array([0.1, 0.0, 0.0])):
        plain, ref = _paper_start(), _paper_start()
        now = ref(tau0)
        ref.correct_from(tau0, now.x_d_W + dp, now.xdot_d_W + dv)
        got = ref(tau0)
        np.testing.assert_allclose(got.x_d_W, now.x_d_W + dp, atol=1e-12)
        np.testing.assert_allclose(got.xdot_d_W, now.xdot_d_W + dv, atol=1e-12)
        np.testing.assert_allclose(got.xddot_d_W, now.xddot_d_W, atol=1e-12)
        T_p = max(math.sqrt(2.0 * H0_PEAK * dp[0] / CORRECT_ACCEL), CORRECT_VEL_S)
        for a, b in zip(ref(tau0 + T_p), plain(tau0 + T_p)):
            np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-12)
        taus = np.arange(tau0, tau0 + T_p, 1e-3)
        gap = np.array([ref(t).x_d_W[0] - plain(t).x_d_W[0] for t in taus])
        if not dp.any():
            assert gap.max() <= 0.1976 * CORRECT_VEL_S * dv[0]  # H1(1/3) = 16/81
            assert gap.max() > 0.19 * CORRECT_VEL_S * dv[0]  # the bound is tight
        else:  # the position part alone: the acceleration of the gap beyond the velocity's
            late = taus > tau0 + CORRECT_VEL_S
            acc = np.diff(gap[late], 2) / 1e-6
            assert 0.4 * CORRECT_ACCEL < np.abs(acc).max() <= 0.5 * CORRECT_ACCEL
