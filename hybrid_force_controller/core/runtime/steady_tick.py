"""
The steady tick: what :meth:`ControllerRuntime.tick` does in the force loop, in two kernels.

With ``tick_impl: compiled`` the runtime first offers each tick to :class:`SteadyTick`. A tick
is steady when nothing but the run itself is under way:

* the runtime is ``RUNNING``, not restarted, with no catch-up, stall, backward clock jump or
  stale input, the reference's time started;
* no tare, ramp of f_d or hand-over from an approach (a user's path is steady: its clock
  advances first, and goes back if the tick turns out not to be);
* the force loop along the gains' n: no normal estimate, no 6-D task, no tool weight, a ready
  force filter, a wrench in the base or the tool frame, base_link the model's root;
* and, from the new inputs, the tool touching (the normal force above the contact threshold)
  at a pose that is not singular, with a finite effort.

Then the tick is pinocchio's kinematics, :func:`~.tick_kernels.steady_front`, the episode the
last tick's errors begin (recovery.py, as the reference's ``_transitions``), pinocchio's two
regressor calls, :func:`~.tick_kernels.steady_back`, and the commit of what they computed into
the runtime's parts (the filter, the clock, the contact, the law's theta_hat and h, the
limiter, the stiffness loop and k_s), then the recovery's statistics as in the reference. Any
other tick, or one the kernels find not steady, returns None and the reference runs
(``tick_impl: python`` always runs it; test_steady_tick compares the two tick by tick). The
kernels change nothing; only an episode begun before a non-finite effort was found stays
begun, and the reference begins it again, which changes nothing more (``Recovery.begin``).
"""
from __future__ import annotations

import importlib
import math
from pathlib import Path
from typing import Any

import numpy as np

from .modes import Mode, TickOutput
from ..law.approach import HANDOVER_S
from ..law.tick_impl import kernels_cached as law_kernels_cached

__all__ = ['kernels_cached', 'SteadyTick']

_EMPTY1, _EMPTY2 = np.empty(0), np.empty((0, 0))


def kernels_cached() -> bool:
    """Say whether every kernel of the compiled tick looks cached (else: a first compile)."""
    cache = Path(__file__).parent / '__pycache__'
    return law_kernels_cached() and any(cache.glob('tick_kernels.*.nbi'))


class SteadyTick:
    """The steady tick of one runtime (module docstring); :meth:`tick` None: not steady."""

    def __init__(self, runtime: Any) -> None:
        self.ticks = 0  # the ticks it ran
        self.enabled = False
        self._rt, model = runtime, runtime.model
        self._k = importlib.import_module(f'{__package__}.tick_kernels')
        self._n, self._m = model.n, model.m
        self._ax = np.array(model.task_axes, dtype=np.int64)
        self._o = self._k.layout(self._n, self._m)
        self._n_sc, self._stale, self._late = len(self._k.SC), self._k.WHY_STALE, self._k.WHY_LATE
        self._size(len(runtime.ctrl.theta_hat))
        self.warm_up()

    def _size(self, p: int) -> None:
        """Allocate the workspace for ``p`` parameters (the model's set: fixed), and its views."""
        o, n, m = self._o, self._n, self._m
        self._W = W = np.zeros(o[15] + p)
        self._sc, self._rows = W[:o[1]], W[o[2]:o[3]].reshape(3, 3)
        self._f_W, self._e = W[o[1]:o[1] + 3], W[o[9]:o[9] + m]
        self._qddot_r, self._V = W[o[13]:o[14]], W[o[14]:o[15]].reshape(2, n)
        self._theta = W[o[15]:]

    def configure(self, params: Any) -> None:
        """Say whether a parameter set allows steady ticks (the static conditions)."""
        rt = self._rt
        self.enabled = (rt.ctrl._tick.fused and not params.orientation.active
                        and not rt._normal.enabled and rt.model._R_W_root is None
                        and rt._in._weight_W is None and hasattr(rt._stiffness.estimator, '_st'))

    def warm_up(self) -> None:
        """Call both kernels once (numba finishes a loaded kernel at its first call)."""
        n, m, z3 = self._n, self._m, np.zeros(3)
        k, eye, sk = self._k, np.eye(3), self._rt.ctrl.stiffness_kernels
        J6 = np.zeros((6, n))
        code = k.steady_front(self._W, n, m, J6, J6, z3, eye, self._ax, np.zeros(n), True,
                              False, -eye[2], 1.0, 0.0, 1e-3, z3, 10.0, 1e-3, eye[2], 0.0, 1.0,
                              0.0, 0.01, 0.5, np.zeros(m), np.zeros(m), 1.0, 1.0, 1.0, 0.0,
                              0.0, 0.0, np.zeros((3, 3, 3)), 1.0, True, _EMPTY2, 1.0, 0.0, 1.0,
                              np.zeros((2, 3)), -math.inf, 0.0, np.zeros((2, 3)),
                              np.zeros((2 * m, 2 * m + 11)), np.eye(n), 0.1)
        P = np.zeros((n, self._theta.size))
        st = np.zeros(len(sk.STATE))
        st[sk.STATE['_k_s']] = 1.0  # a k_s command of 1 N/m, the rest 0
        k.steady_back(self._W, n, m, P, P, P, False, self._theta.copy(), 1.0, 0.0,
                      np.eye(self._theta.size), 1.0, 0.1, 0.0, 1e-3, self._theta - 1.0,
                      self._theta + 1.0, 0.0, 1.0, 0.0, 1e-3, np.zeros(n), 1.0, np.zeros(n),
                      True, np.ones(n), np.empty(n), st, np.ones(len(sk.CONFIG)), 0.0, 0.0,
                      1.0, z3, 1e-3, False)
        self._W[:] = 0.0
        assert code in (0, 2)

    def tick(self, t: float) -> TickOutput | None:
        """Run the steady tick at ``t``; None when it is not one (nothing changed)."""
        rt = self._rt
        if not self.enabled or rt.mode is not Mode.RUNNING or rt._restarted:
            return None
        clock, inputs, motion, ctrl = rt._clock, rt._in, rt._motion, rt.ctrl
        period, s, w = rt._period, inputs.state, inputs.wrench
        if (clock.t0 is None or t < clock.t_tick - period or s is None or w is None
                or t - clock.t_tick > rt.recovery.cfg.stall_periods * period
                or rt._catch_up.active or rt._catch_up.silent or inputs.tare is not None
                or motion.force_ramping or ctrl._moving is not None
                or (s.t - motion.handover.t_c) / HANDOVER_S < 1.0 or rt._stiffness._paused
                or not inputs.filter.ready or inputs.stale(t)):
            return None
        frame = w.frame_id
        if frame != rt.model.base_link and frame != rt.model.end_effector_link:
            return None
        path = motion.path  # its clock advances first, as the reference's tick does it
        saved = None if path is None else (path.sigma, path.rho, path.rho_rate, path.going)
        if path is not None:
            motion.advance_path(clock.state_dt(s.t, period), True)  # steady: running, touching
        if self._front(rt, clock, inputs, motion, ctrl, s, w, frame):
            kind = rt.recovery.triggered()
            if kind:  # the last tick's errors begin an episode (or it goes on): theta_hat held
                rt._begin(kind, t)
            tau = self._back(rt, ctrl, s)
            if tau is not None:
                return self._commit(rt, t, clock, inputs, motion, ctrl, s, tau)
        if path is not None:  # not steady: the path's clock as it was
            path.sigma, path.rho, path.rho_rate, path.going = saved
        return None

    def _front(self, rt, clock, inputs, motion, ctrl, s, w, frame: str) -> bool:
        """Run pinocchio's kinematics and steady_front; False: not steady."""
        model, n, m = rt.model, self._n, self._m
        self._p_W, R, J6, Jdot6 = model.frame_kinematics(s.q, s.qdot)
        d, k, ref, flt = ctrl._d, ctrl._k, motion.ref, inputs.filter
        g, tau = d.gains, s.t - clock.t0
        sine = ref.path is None and ref.x_hold_W is None
        return 0 == self._k.steady_front(
            self._W, n, m, J6, Jdot6, self._p_W, R, self._ax, s.qdot, inputs._new_wrench,
            frame != model.base_link, w.F_S, w.t, inputs._wrench_prev_t, rt._period, flt._y,
            flt.cutoff_hz, flt._dt, rt._normal.n_W, ctrl.f_d, s.t, clock.t_used,
            rt._params.runtime.max_integration_dt, flt._a, motion._n_of_task(), d.n, k.c,
            g.lambda1, k.lambda2, ctrl.h, ctrl.fdot_d, k.c_rate, ref.sine._K, ref.sine.omega,
            sine, _EMPTY2 if sine else ref._base_rows(tau), tau, ref.tau_b, ref._tb,
            ref._offsets, ref._corr_tau, ref._corr_tp, ref._corr, d.G,
            model.inertia_inverse(s.q) if n > m else _EMPTY2, g.singular_sigma)

    def _back(self, rt, ctrl, s) -> np.ndarray | None:
        """Run pinocchio's regressors and steady_back; the limited effort (None: not finite)."""
        model, d, k, loop = rt.model, ctrl._d, ctrl._k, rt._stiffness
        g, sc, lim, est = d.gains, self._sc, rt._command.limiter, loop.estimator
        P, known = model.regressor_map
        dt_int = float(sc[1])
        adapt = sc[10] == 0.0 and not rt.recovery.frozen  # not damped, no episode holding it
        self._dt_adapt = dt_int if adapt else 0.0
        last, tau = lim._last, np.empty(self._n)
        finite = self._k.steady_back(
            self._W, self._n, self._m, *model.regressor_pair(s.q, self._V, self._qddot_r), P,
            known, ctrl.theta_hat, g.k_d, g.k_null, d.Gamma_inv, g.k_a, g.adapt_error_limit,
            g.adapt_dead_zone, self._dt_adapt, g.theta_min, g.theta_max, ctrl.h, k.h_limit,
            ctrl.f_d, dt_int, s.qdot, lim.max_rate, _EMPTY1 if last is None else last,
            last is not None, lim.limits, tau, est._st, est._cf, *loop._n, self._p_W,
            float(sc[0]), loop._known)
        return tau if finite else None

    def _commit(self, rt, t, clock, inputs, motion, ctrl, s, tau) -> TickOutput:
        """Write the kernels' results into the runtime's parts, as the reference's tick does."""
        (dt, dt_int, why, f_n, x_seen, r_n, rdot_n, _, f_dt, f_a, state, h, saturated,
         e_norm, known, k_s, log_rate) = self._sc[:self._n_sc].tolist()
        counters, flt = rt.counters, inputs.filter
        counters['ticks'] += 1
        self.ticks += 1
        clock.t_tick = max(clock.t_tick, t)
        if inputs._new_wrench:
            flt._y[:] = self._f_W
            flt._dt, flt._a, inputs._new_wrench = f_dt, f_a, False
        rt._fresh_since = min(rt._fresh_since, t)
        if why == self._stale:
            counters['stale_ticks'] += 1
        else:
            clock.t_used = s.t
            counters['late_states'] += why == self._late
        rt._contact.active, rt._contact._t_below = True, None
        motion.x_seen = x_seen
        ctrl._tick.steady_steps += 1
        ctrl.damped, ctrl.e_w = state == 1.0, None
        if dt_int > 0.0:
            if self._dt_adapt > 0.0:
                theta = self._theta.copy()
                ctrl.theta_hat = theta if ctrl._project is None else ctrl._project(theta)
            ctrl.h = h
        counters['singular_ticks'] += ctrl.damped
        if dt > 0.0:  # the stiffness estimate stepped (steady_back): its loop, k_s into the law
            loop = rt._stiffness
            loop.contacts += not loop._touching
            loop._touching, loop._known = True, known == 1.0
            if loop.estimator.config.enabled:
                ctrl.set_k_s(k_s, log_rate)
        motion.r_n, motion.rdot_n = r_n, rdot_n
        rt.recovery.note(t, abs(f_n - ctrl.f_d), e_norm, True, ctrl.theta_hat)
        return self._output(rt, clock, tau, saturated)

    def _output(self, rt, clock, tau, saturated: float) -> TickOutput:
        """Return what the reference's ``_output`` returns for a running tick."""
        cmd, counters = rt._command, rt.counters
        counters['saturated_ticks'] += saturated == 1.0
        cmd.limiter._last = tau
        tau = cmd.tau_last = cmd.blend(tau, clock.t_tick)
        rt.mode, rt.status = Mode.RUNNING, 'running'
        rows, e_W = self._rows.copy(), np.zeros(3)
        e_W[rt.model.task_index] = self._e
        return TickOutput(tau if cmd.order is None else tau[cmd.order], Mode.RUNNING, self._p_W,
                          rows[0], rt._in.filter.value.copy(), rt.f_d_W, e_W,
                          rt.ctrl.theta_hat.copy(), True, 'running', rt._stiffness.k_hat,
                          rt._motion.path_progress(), rows[1], rt._normal.n_W, None)
