"""Phase-2 prototype (issue 13): k_s := k_hat in the closed loop, without editing the core.

Not part of the package: a subclass of the control law and a copy of the offline loop of
``core/scenario.py`` (which the lead is rewriting), so that the integration proposal can
be measured before it is implemented. What each tick does (module docstring of
``core/stiffness.py`` for (S0)-(S8)):

1. the control law runs with the current k_s (one tick of lag for the estimate);
2. the estimator takes ``f_n = n^T f`` (filtered, as the law sees it), ``x_n = n^T x`` of
   the same (delayed) sample and the controller's contact test;
3. ``k_s = k_s_command(dt)`` (S7); when it moved, the law gets new gains:

   * ``c = 1/k_s`` in r, rdot and e (eq. 11, scaled form);
   * ``lambda2 = lambda2_0 k_s0 / k_s`` (mode ``'bandwidth'``): the normal loop with e = 0,
     ``hddot + (k/k_s) lambda1 hdot + lambda2 k h = 0``, becomes
     ``hddot + lambda1 hdot + lambda2_0 k_s0 h = 0`` at k_s = k: the damping and bandwidth
     the user's gains give at k = k_s0, whatever the surface;
   * ``Gamma = Gamma_0 k_s / k_s0``: the adaptation (26) acts on ``k_s e``; this keeps
     ``Gamma^-1 k_s = Gamma_0^-1 k_s0``, the adaptation speed of the user's gains;
   * bumpless: ``h <- h lambda2_old / lambda2_new`` keeps ``lambda2 h`` (a velocity in r)
     continuous;
   * rdot gets the term of the varying compliance, ``-cdot lambda1 df_n n`` with
     ``cdot = -c d(ln k_s)/dt`` (the law differentiates r with c constant).

Modes: ``'off'`` (k_s fixed, the current controller), ``'k_s'`` (k_s := k_hat only, the
literal reading), ``'bandwidth'`` (all of the above).

    .venv/bin/python test/stiffness_prototype.py [--extras]   # the tables of the report
"""
from __future__ import annotations

import dataclasses
import sys
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hybrid_force_controller.core.control_law import (HybridForceController,  # noqa: E402
                                                      in_contact)
from hybrid_force_controller.core.environment import ElasticSurface  # noqa: E402
from hybrid_force_controller.core.filters import LowPassFilter  # noqa: E402
from hybrid_force_controller.core.params import ControllerParams  # noqa: E402
from hybrid_force_controller.core.reference import SineReference, blend_start  # noqa: E402
from hybrid_force_controller.core.robot_model import RobotModel  # noqa: E402
from hybrid_force_controller.core.scenario import PAPER_Q0, make_controller_params  # noqa: E402
from hybrid_force_controller.core.simulator import ArmSimulator  # noqa: E402
from hybrid_force_controller.core.stiffness import (StiffnessConfig,  # noqa: E402
                                                    StiffnessEstimator)

MODES = ('off', 'k_s', 'bandwidth')


class StiffnessAwareController(HybridForceController):
    """The control law with k_s (and, in mode ``'bandwidth'``, lambda2 and Gamma) set from
    the stiffness estimate each tick. ``nominal`` is the user's parameter set."""

    def __init__(self, model: RobotModel, params: ControllerParams, estimator: StiffnessEstimator,
                 mode: str = 'bandwidth', rdot_term: bool = True, scale_gamma: bool = True) -> None:
        if mode not in MODES:
            raise ValueError(f'mode must be one of {MODES}, got {mode!r}')
        self.nominal, self.estimator, self.mode, self.rdot_term = params, estimator, mode, rdot_term
        self.scale_gamma = scale_gamma
        self.log_rate = 0.0
        super().__init__(model, params)

    def set_nominal(self, params: ControllerParams) -> None:
        """A user parameter change (e.g. f_d): keep the current k_s and its gains."""
        self.nominal = params
        self._apply(self.params.k_s, force=True)

    def gains_for(self, k_s: float) -> ControllerParams:
        """The nominal set with k_s and, in mode 'bandwidth', lambda2 and Gamma rescaled."""
        p0 = self.nominal
        if self.mode != 'bandwidth':
            return dataclasses.replace(p0, k_s=k_s)
        ratio = p0.k_s / k_s
        return dataclasses.replace(p0, k_s=k_s, lambda2=p0.lambda2 * ratio,
                                   Gamma=p0.Gamma / ratio if self.scale_gamma else p0.Gamma)

    def _apply(self, k_s: float, force: bool = False) -> None:
        if k_s == self.params.k_s and not force:
            return
        new = self.gains_for(k_s)
        if self.mode == 'bandwidth':
            self.h *= self.params.lambda2 / new.lambda2  # lambda2 h continuous
        self.set_params(new)

    def reference_velocity(self, kin, ref, f):
        r, rdot, e, df_n = super().reference_velocity(kin, ref, f)
        if self.rdot_term and self.log_rate != 0.0:
            _, n, _, _, c = self._derived
            rdot = rdot + (c * self.log_rate * self.params.lambda1 * df_n) * n
        return r, rdot, e, df_n

    def after_step(self, f_n: float, x_n: float, dt: float, contact: bool) -> None:
        """Feed the estimator with this tick's sample and set k_s for the next tick."""
        self.estimator.update(f_n, x_n, dt, contact)
        if self.mode == 'off':
            return
        k_s = self.estimator.k_s_command(dt)
        self.log_rate = self.estimator.k_s_log_rate
        self._apply(k_s)


@dataclass(frozen=True)
class PrototypeConfig:
    """Like ScenarioConfig, plus the estimator mode and an optional f_d step."""

    k: float = 1700.0
    duration: float = 20.0
    delay_steps: int = 2
    noise_sigma: float = 0.0
    seed: int = 0
    theta_hat0_scale: float = 1.0
    substeps: int = 2
    mode: str = 'bandwidth'
    rdot_term: bool = True
    scale_gamma: bool = True
    f_d_step: tuple[float, float] | None = None  # (time s, new f_d N)
    k_s_fixed: float | None = None  # the gains of `mode` at this k_s, the estimate unused
    stiffness: StiffnessConfig = StiffnessConfig(enabled=True)
    overrides: dict[str, Any] = field(default_factory=dict)


@dataclass
class PrototypeResult:
    t: np.ndarray
    x_W: np.ndarray
    x_d_W: np.ndarray
    f_W: np.ndarray
    f_true_W: np.ndarray
    f_d_W: np.ndarray
    theta_hat: np.ndarray
    in_contact: np.ndarray
    tau: np.ndarray
    n_W: np.ndarray
    theta_true: np.ndarray
    theta_names: tuple[str, ...]
    k_hat: np.ndarray
    k_s: np.ndarray
    valid: np.ndarray


def run_prototype(cfg: PrototypeConfig, model: RobotModel | None = None) -> PrototypeResult:
    """The loop of core/scenario.run_scenario with the stiffness-aware controller."""
    model = RobotModel.from_urdf() if model is None else model
    theta0 = model.theta_nominal * cfg.theta_hat0_scale
    params = make_controller_params(model, {'theta_hat0': theta0.tolist(), **cfg.overrides})
    est = StiffnessEstimator(dataclasses.replace(
        cfg.stiffness, k_max=params.k_max, k_hat0=params.k_s,
        force_filter_hz=params.force_filter_hz))
    ctrl = StiffnessAwareController(model, params, est, cfg.mode, cfg.rdot_term, cfg.scale_gamma)
    if cfg.k_s_fixed is not None:
        est = ctrl.estimator = StiffnessEstimator(dataclasses.replace(
            est.config, enabled=False, k_hat0=cfg.k_s_fixed))
        ctrl._apply(cfg.k_s_fixed)
    q0 = np.array(PAPER_Q0)
    p0 = model.kinematics(q0, np.zeros(model.n)).p_W
    sim = ArmSimulator(model, ElasticSurface.create(cfg.k, p0, params.n), q0,
                       substeps=cfg.substeps, noise_sigma=cfg.noise_sigma, seed=cfg.seed)
    sine = SineReference(params.ref_center, params.ref_amplitude, params.ref_omega)
    P_t = np.eye(3) - np.outer(params.n, params.n)
    offset, offset_vel = P_t @ (p0 - sine(0.0).x_d_W), P_t @ -sine(0.0).xdot_d_W
    dt = 1.0 / params.rate_hz
    steps = int(round(cfg.duration / dt))
    filt = LowPassFilter(params.force_filter_hz)
    log = {name: [] for name in ('x', 'f', 'f_true', 'f_d', 'theta', 'contact', 'tau', 'k_hat',
                                 'k_s', 'valid')}
    meas = sim.measure()
    pending = deque([meas] * (cfg.delay_steps + 1), maxlen=cfg.delay_steps + 1)
    n_W = params.n
    for i in range(steps):
        if cfg.f_d_step is not None and i == int(round(cfg.f_d_step[0] / dt)):
            ctrl.set_nominal(dataclasses.replace(ctrl.nominal, f_d=cfg.f_d_step[1]))
        seen = pending[0]
        filt.update(seen.f_W, dt)
        ref = blend_start(sine(seen.t), offset, seen.t, params.ref_blend_time, offset_vel)
        out = ctrl.step(seen.q, seen.qdot, filt.value, ref, dt)
        f_n = float(n_W @ filt.value)
        ctrl.after_step(f_n, float(n_W @ ctrl.last_kin.p_W), dt,
                        in_contact(f_n, ctrl.params.f_d))
        for name, value in (('x', meas.p_W), ('f', meas.f_W), ('f_true', meas.f_true_W),
                            ('f_d', ctrl.params.f_d * n_W), ('theta', ctrl.theta_hat.copy()),
                            ('contact', meas.in_contact), ('tau', out.tau),
                            ('k_hat', est.k_hat), ('k_s', ctrl.params.k_s),
                            ('valid', est.valid)):
            log[name].append(value)
        meas = sim.step(out.tau, dt)
        pending.append(meas)
    t = np.arange(steps) * dt
    x_d = sine.center_W + np.outer(np.sin(sine.omega * t), sine.amplitude_W)
    a = {name: np.array(v) for name, v in log.items()}
    return PrototypeResult(t, a['x'], x_d, a['f'], a['f_true'], a['f_d'], a['theta'],
                           a['contact'], a['tau'], n_W.copy(), model.theta_nominal.copy(),
                           model.theta_names, a['k_hat'], a['k_s'], a['valid'])


def settling_time(t: np.ndarray, y: np.ndarray, t_step: float, y0: float, y1: float,
                  band: float = 0.02) -> float:
    """Time after ``t_step`` from which ``|y - y1| <= band |y1 - y0|`` holds (inf: never)."""
    after = t >= t_step
    outside = np.flatnonzero(np.abs(y[after] - y1) > band * abs(y1 - y0))
    if outside.size == 0:
        return 0.0
    if outside[-1] + 1 >= after.sum():
        return float('inf')
    return float(t[after][outside[-1] + 1] - t_step)


# ---------------------------------------------------------------- study
def closed_loop_case(k: float, scale: float, noise: float = 0.0, duration: float = 20.0,
                     mode: str = 'bandwidth', **kw) -> dict:
    """Targets of one closed-loop run (t >= 5 s), and the estimate's convergence."""
    from hybrid_force_controller.tools.analysis import RunLog, compute_metrics
    from stiffness_study import time_within
    res = run_prototype(PrototypeConfig(k=k, theta_hat0_scale=scale, noise_sigma=noise,
                                        duration=duration, mode=mode, **kw))
    m = compute_metrics(RunLog.from_result(res), t_start=5.0)
    t_c = float(res.t[np.argmax(res.in_contact)])
    late = res.t >= t_c + 2.0
    return dict(res=res, metrics=m, t_10pct=time_within(res.t, res.k_hat, k, 0.10, t_c),
                t_k_s_10pct=time_within(res.t, res.k_s, k, 0.10, t_c),
                final_err=float(res.k_hat[-1] - k) / k,
                max_err_late=float(np.max(np.abs(res.k_hat[late] - k))) / k)


def step_case(k: float, mode: str, t_step: float = 10.0, duration: float = 13.0) -> dict:
    """f_d 1 -> 2 N at t_step (a parameter change), masses 50 % low, 2 periods of delay."""
    res = run_prototype(PrototypeConfig(k=k, theta_hat0_scale=0.5, mode=mode,
                                        duration=duration, f_d_step=(t_step, 2.0)))
    f_n = res.f_true_W @ res.n_W
    after = res.t >= t_step
    return dict(res=res, t_settle=settling_time(res.t, f_n, t_step, 1.0, 2.0),
                overshoot=float(f_n[after].max() - 2.0),
                contact_lost=bool((~res.in_contact[after]).any()))


def _print_closed_loop() -> None:
    print('Closed loop, prototype (mode bandwidth: k_s, lambda2, Gamma from k_hat), '
          'delay_steps=2, 20 s')
    print('  k N/m  masses  noise  t_10% k_hat s  t_10% k_s s  final err  '
          'rms f_n err N  rms pos err mm  contact lost s')
    for noise in (0.0, 0.05):
        for k in (300.0, 500.0, 1700.0, 5000.0):
            for scale in (0.5, 1.5):
                r = closed_loop_case(k, scale, noise)
                m = r['metrics']
                print(f"  {k:5.0f}  {scale:6.1f}  {noise:5.2f}  {r['t_10pct']:12.3f}  "
                      f"{r['t_k_s_10pct']:11.3f}  {100 * r['final_err']:+8.2f}%  "
                      f"{m['rms_force_error_n']:13.4f}  {1e3 * m['rms_position_error_m']:13.4f}"
                      f"  {m['contact_lost_s']:14.3f}")
    print('Force step f_d 1 -> 2 N at t = 10 s (true force, 2 % of the step = 0.02 N band)')
    print('  k N/m  mode        settling s  overshoot N  contact lost')
    for k in (500.0, 5000.0):
        for mode in MODES:
            r = step_case(k, mode)
            print(f"  {k:5.0f}  {mode:10s}  {r['t_settle']:10.3f}  {r['overshoot']:11.3f}  "
                  f"{r['contact_lost']}")


def _print_extras() -> None:
    """The figures behind the phase-2 proposal: Gamma scaling, estimate errors, cost."""
    import timeit
    print('Adaptation with and without Gamma = Gamma_0 k_s/k_s0 (masses 50 % low, 20 s)')
    for k in (300.0, 1700.0):
        for mode, scale_gamma in (('off', True), ('bandwidth', True), ('bandwidth', False)):
            res = run_prototype(PrototypeConfig(k=k, theta_hat0_scale=0.5, mode=mode,
                                                scale_gamma=scale_gamma))
            off = np.flatnonzero(np.any(np.abs(res.theta_hat - res.theta_true)
                                        > 0.05 * res.theta_true, axis=1))
            t5 = res.t[off[-1] + 1] if off.size and off[-1] + 1 < res.t.size else float('inf')
            print(f'  k {k:5.0f}  {mode:9s}  scale_gamma {scale_gamma!s:5s}  '
                  f'theta_hat within 5 % from t = {t5:.2f} s')
    print('Fixed k_s = k / ratio with the gains of mode bandwidth (8 s, t >= 5 s)')
    for k, ratio in ((500.0, 3.0), (500.0, 5.0), (5000.0, 1.5), (5000.0, 3.0), (5000.0, 5.0)):
        m = closed_loop_case(k, 0.5, duration=8.0, k_s_fixed=k / ratio)['metrics']
        print(f"  k {k:5.0f}  k/k_s {ratio:3.1f}  rms f_n err {m['rms_force_error_n']:.4f} N  "
              f"contact lost {m['contact_lost_s']:.3f} s")
    print('k_s rate limit and the rdot term (k = 300, masses 50 % low, 6 s): true force error '
          'over [0.6, 5) s')
    for rate in (1.0, 2.0, 10.0, 20.0, 100.0):
        for rdot_term in (True, False):
            st = StiffnessConfig(enabled=True, k_s_rate_down=rate,
                                 k_s_time_constant=0.0 if rate == 100.0 else 0.1)
            res = run_prototype(PrototypeConfig(k=300.0, theta_hat0_scale=0.5, duration=6.0,
                                                stiffness=st, rdot_term=rdot_term))
            err = (res.f_true_W @ res.n_W - 1.0)[(res.t >= 0.6) & (res.t < 5.0)]
            print(f'  rate_down {rate:5.1f}/s  rdot term {rdot_term!s:5s}  '
                  f'max {np.abs(err).max():.4f} N  rms {np.sqrt(np.mean(err ** 2)):.4f} N  '
                  f'k_s(1 s) {res.k_s[1000]:.0f} N/m')
    model = RobotModel.from_urdf()
    params = make_controller_params(model, {})
    ctrl = StiffnessAwareController(model, params, StiffnessEstimator(StiffnessConfig()))
    q, qdot, f_W = np.array(PAPER_Q0), np.array([0.1, -0.2]), np.array([0.0, -1.0, 0.0])
    ref = SineReference(params.ref_center, params.ref_amplitude, params.ref_omega)(0.3)
    sets = [ctrl.gains_for(float(k)) for k in np.linspace(300.0, 6000.0, 50)]
    est = StiffnessEstimator(StiffnessConfig(enabled=True))
    jobs = {'control step': (lambda: ctrl.step(q, qdot, f_W, ref, 1e-3), 1),
            'set_params': (lambda: [ctrl.set_params(p) for p in sets], len(sets)),
            'estimator update + k_s_command': (
                lambda: [(est.update(1.0, -1.61 + 1e-5 * (i % 3), 1e-3, True),
                          est.k_s_command(1e-3)) for i in range(50)], 50)}
    cost = {name: min(timeit.repeat(fn, number=200, repeat=5)) / (200 * per)
            for name, (fn, per) in jobs.items()}
    print('Cost relative to one control step (shared machine: ratios only)')
    for name, c in cost.items():
        print(f"  {name:32s} {c / cost['control step']:.2f}")


if __name__ == '__main__':
    _print_closed_loop()
    if '--extras' in sys.argv:
        _print_extras()
